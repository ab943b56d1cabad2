"""The package layout, found rather than listed (everything else is in pyproject.toml).

The charter's top-level folders are the subpackages of ``enginebench``: ``cli/`` is
``enginebench.cli`` and so on, and the folder ``enginebench/`` is the root package. Below
each folder, setuptools finds the subpackages itself, so a new folder with an
``__init__.py`` is packaged without editing a list. Each folder's ``__init__.py`` refuses
to be imported under its bare name (``import methods`` from the checkout root), so no
module can be loaded twice.
"""

from setuptools import find_packages, setup

FOLDERS = ("cli", "datasets", "experiments", "methods", "reports", "results")

package_dir = {"enginebench": "enginebench", **{f"enginebench.{folder}": folder for folder in FOLDERS}}
packages = ["enginebench"]
for folder in FOLDERS:
    packages += [f"enginebench.{folder}", *(f"enginebench.{folder}.{sub}" for sub in find_packages(folder))]

setup(package_dir=package_dir, packages=packages)
