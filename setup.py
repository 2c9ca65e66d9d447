"""Packages are found, never listed: every package under ``hybridfit/``, and the reference
plugins under ``plugins/`` installed as ``hybridfit_plugins`` (so they can never clash with
another distribution's top-level ``plugins``). Everything else is in pyproject.toml.

(pyproject.toml alone cannot rename a found folder; this file exists only for that.)
"""

from setuptools import find_packages, setup

PLUGINS_FOLDER, PLUGINS_PACKAGE = "plugins", "hybridfit_plugins"

plugins = [PLUGINS_PACKAGE + name[len(PLUGINS_FOLDER):]
           for name in find_packages(include=[PLUGINS_FOLDER, f"{PLUGINS_FOLDER}.*"])]
setup(
    packages=find_packages(include=["hybridfit", "hybridfit.*"]) + plugins,
    package_dir={PLUGINS_PACKAGE: PLUGINS_FOLDER},
)
