"""Ships the top-level ``datamodules/`` and ``sweeps/`` folders inside the package.

Everything else about the build is in pyproject.toml. The recipe folders stay at the top
of the repository (where the docs and ``make`` use them) and are added to ``build_py``'s
package data as ``robomorph/_recipes/<folder>/``, so the wheel and the sdist carry them
without a second copy in git. An editable install copies nothing: the package then reads
the folders beside it (``robomorph.core.recipes``).
"""

import os

from setuptools import setup
from setuptools.command.build_py import build_py

RECIPE_FOLDERS = ("datamodules", "sweeps")
SUFFIXES = (".yaml", ".yml")


class build_py_with_recipes(build_py):
    """``build_py`` whose package data also holds the recipe folders."""

    def _recipe_data_files(self):
        # The (package, source dir, build dir, file names) tuples build_py copies,
        # lists in the sdist and reports as its outputs.
        entries = []
        for folder in RECIPE_FOLDERS:
            names = sorted(n for n in os.listdir(folder) if n.endswith(SUFFIXES)) if os.path.isdir(folder) else []
            if not names:
                raise FileNotFoundError(f"{folder}/ holds no recipe files: build from the repository root")
            entries.append((f"robomorph._recipes.{folder}", folder,
                            os.path.join(self.build_lib, "robomorph", "_recipes", folder), names))
        return entries

    def _get_data_files(self):
        return super()._get_data_files() + self._recipe_data_files()

    def get_data_files_without_manifest(self):
        return super().get_data_files_without_manifest() + self._recipe_data_files()


setup(cmdclass={"build_py": build_py_with_recipes})
