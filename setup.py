"""Package layout that pyproject.toml cannot express on its own.

The code lives in ``framework/`` (``slamfront``) and ``plugins/`` (``slamfront_plugins``).
The shipped recipes, sweeps and Foxglove layouts stay at the repository's top level,
where users and the docs look for them, and are packaged from there as the
sub-packages ``slamfront.resources.<folder>``, read at run time with
``importlib.resources`` (:mod:`slamfront.resources`). Mapping them here (rather than
copying them in a build step) keeps editable installs (``make setup``) and wheels alike:
a recipe added to ``recipes/`` is shipped by the next wheel and seen at once by an
editable install.
"""

from setuptools import find_packages, setup

CODE_ROOTS = ("framework", "plugins")
RESOURCES = {"recipes": ["*.yaml"], "sweeps": ["*.yaml"], "foxglove": ["*.json"]}
"""Top-level folder -> the files of it that are shipped."""

packages: list[str] = []
package_dir: dict[str, str] = {}
for root in CODE_ROOTS:
    for name in find_packages(root):
        packages.append(name)
        package_dir[name] = f"{root}/{name.replace('.', '/')}"
for folder in RESOURCES:
    packages.append(f"slamfront.resources.{folder}")
    package_dir[f"slamfront.resources.{folder}"] = folder

setup(
    packages=packages,
    package_dir=package_dir,
    package_data={
        "slamfront.resources": ["*.json"],  # the pinned-data manifest
        **{f"slamfront.resources.{folder}": patterns for folder, patterns in RESOURCES.items()},
    },
)
