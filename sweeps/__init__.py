"""The shipped sweep files, packaged as ``slamfront.resources.sweeps`` (see setup.py); list them with `slamfront sweeps`."""
