"""Build hook: wheels carry the bundled scenes and TLE sets.

The repository's top-level ``scenes/`` and ``ephemeris/`` folders are their source of truth;
building the package copies them into it as ``virtualgps/_bundled/`` (see
:mod:`virtualgps.bundled`), so an installed virtualgps runs anywhere. Everything else is in
pyproject.toml.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

BUNDLED = ("scenes", "ephemeris")


class BuildPyWithBundledData(build_py):
    """build_py, then the bundled data folders into the built package."""

    def run(self) -> None:
        super().run()
        root = Path(__file__).resolve().parent
        for name in BUNDLED:
            dst = Path(self.build_lib) / "virtualgps" / "_bundled" / name
            if dst.exists():
                shutil.rmtree(dst)
            shutil.copytree(root / name, dst)


setup(cmdclass={"build_py": BuildPyWithBundledData})
