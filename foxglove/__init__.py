"""The shipped Foxglove layouts, packaged as ``slamfront.resources.foxglove`` (see setup.py); `slamfront layout` prints the path."""
