"""The shipped recipes, packaged as ``slamfront.resources.recipes`` (see setup.py); list them with `slamfront recipes`."""
