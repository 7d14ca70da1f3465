"""slamfront's built-in plugins, one sub-package per kind.

They are registered through the ``slamfront`` entry-point group in pyproject.toml, the
same way a third-party package registers its own; each sub-package's ``__init__``
implements that kind's hook and returns its plugin classes.
"""
