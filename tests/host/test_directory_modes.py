"""Directories the host writes as a whole (quad sets, converted recordings) respect the umask."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from elphel_host.fileio import replacing_directory


@pytest.mark.parametrize("umask", [0o022, 0o002, 0o077])
def test_replacing_directory_gets_the_mode_of_mkdir(tmp_path: Path, umask: int) -> None:
    old = os.umask(umask)
    try:
        with replacing_directory(tmp_path / "quad") as tmp:
            (tmp / "quad.json").write_text("{}")
        (tmp_path / "plain").mkdir()
    finally:
        os.umask(old)
    mode = stat.S_IMODE((tmp_path / "quad").stat().st_mode)
    assert mode == 0o777 & ~umask
    assert mode == stat.S_IMODE((tmp_path / "plain").stat().st_mode)
