"""Packaging: the repository keeps the design card's top level (``core/``, ``app/``, ``widgets/``,
``resources/``), and what gets installed is one import name, ``evpose``: the repository root is the
``evpose`` package (its ``__init__.py`` and ``__main__.py``) and each role folder one of its
subpackages. Subpackages are discovered, so a new one cannot be left out of a wheel; ``tests/``,
``bench/`` and ``docs/`` are not installed. Metadata and dependencies live in ``pyproject.toml``."""
from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

ROLE_FOLDERS = ("core", "app", "widgets", "resources")


class BuildPy(build_py):
    """The root package holds only ``__init__`` and ``__main__`` (never this script)."""

    def find_package_modules(self, package, package_dir):
        modules = super().find_package_modules(package, package_dir)
        return [m for m in modules if package != "evpose" or m[1] in ("__init__", "__main__")]


found = find_packages(include=[*ROLE_FOLDERS, *(f"{r}.*" for r in ROLE_FOLDERS)])
setup(packages=["evpose", *(f"evpose.{p}" for p in found)], package_dir={"evpose": "."},
      cmdclass={"build_py": BuildPy})
