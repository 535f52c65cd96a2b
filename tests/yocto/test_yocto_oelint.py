"""oelint-adv reports nothing on the layer, for each release the layer supports."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.yocto.layer import LAYER, Recipe, recipe_files

CONFIG = LAYER / ".oelint.cfg"


def _oelint(files: list[Path], release: str) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("oelint-adv", path=str(Path(sys.executable).parent)) or shutil.which(
        "oelint-adv"
    )
    assert exe, "oelint-adv is not installed (requirements-dev.txt lists it)"
    env = {**os.environ, "OELINT_CONFIG": str(CONFIG)}
    env.pop("OELINT_SKIP_CONFIG", None)
    return subprocess.run(
        [exe, "--release", release, *map(str, files)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )


def _series() -> list[str]:
    return Recipe.read(LAYER / "conf" / "layer.conf").words("LAYERSERIES_COMPAT_elphel")


@pytest.mark.parametrize("release", _series())
def test_oelint_reports_nothing(release: str) -> None:
    files = [*recipe_files(), *sorted((LAYER / "conf").rglob("*.conf"))]
    result = _oelint(files, release)
    findings = (result.stdout + result.stderr).strip()
    assert result.returncode == 0 and not findings, findings


def test_oelint_with_the_layer_settings_still_finds_faults(tmp_path: Path) -> None:
    bad = tmp_path / "bad_1.0.bb"
    bad.write_text('SUMMARY = "x"\nLICENSE = "MIT"\nRDEPENDS_${PN} = "foo"\n')
    result = _oelint([bad], "wrynose")
    assert result.returncode == 1
    assert "oelint.vars.mispell" in result.stderr
