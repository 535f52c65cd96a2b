"""The browser page ships with the daemon: every file under elphel_camd/web is package data.

The recipe builds the daemon's wheel (python_setuptools_build_meta), so what the
pyproject's package-data holds is what lands on the camera.
"""

from __future__ import annotations

import fnmatch
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CAMERA = ROOT / "target" / "camera"
PACKAGE = CAMERA / "src" / "elphel_camd"
RECIPE = ROOT / "yocto/meta-elphel/recipes-camera/elphel-camd/elphel-camd_0.1.0.bb"


def test_every_page_file_is_package_data() -> None:
    pyproject = tomllib.loads((CAMERA / "pyproject.toml").read_text())
    globs = pyproject["tool"]["setuptools"]["package-data"]["elphel_camd"]
    files = sorted(p.relative_to(PACKAGE).as_posix() for p in (PACKAGE / "web").rglob("*"))
    files = [f for f in files if (PACKAGE / f).is_file()]
    assert "web/index.html" in files
    missing = [f for f in files if not any(fnmatch.fnmatchcase(f, g) for g in globs)]
    assert missing == [], f"not shipped in the wheel: {missing}"


def test_the_recipe_installs_the_wheel_with_its_package_data() -> None:
    text = RECIPE.read_text()
    assert "inherit python_setuptools_build_meta" in text
    assert "python3-pillow" in text  # the previews' JPEG encoder


def test_the_page_asks_for_nothing_outside_the_daemon() -> None:
    for path in (PACKAGE / "web").rglob("*"):
        if path.is_file():
            text = path.read_text()
            for scheme in ("http://", "https://", "//cdn", "@import url("):
                assert scheme not in text, f"{path.name} refers to {scheme}"
