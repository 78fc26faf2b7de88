"""Build hook: a wheel (and ``pip install .``) carries the top-level files dcm ships with as ``dcm/_shipped/``,
so an installed package finds them without a source tree (dcm/shipped.py). The top-level folders stay their one
source: nothing is copied in the tree, and an editable install reads them in place."""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
SHIPPED = {  # folder -> the files of it that ship (MANIFEST.in lists the same for an sdist)
    "conf": ["**/*.yaml"],
    "models": ["*.ckpt", "*.json", "README.md"],
    "data/demos": ["*.yaml"],
    "data/waypoints": ["*.csv"],
}


class BuildWithShippedFiles(build_py):
    def run(self) -> None:
        super().run()
        if self.editable_mode:  # the source tree's own folders are read in place
            return
        target = Path(self.build_lib) / "dcm" / "_shipped"
        shutil.rmtree(target, ignore_errors=True)  # no file removed from the tree lingers from an earlier build
        for folder, patterns in SHIPPED.items():
            for pattern in patterns:
                for source in sorted((ROOT / folder).glob(pattern)):
                    dest = target / source.relative_to(ROOT)
                    self.mkpath(str(dest.parent))
                    self.copy_file(str(source), str(dest))


setup(cmdclass={"build_py": BuildWithShippedFiles})
