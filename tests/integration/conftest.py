"""Fixtures of the integration tests: a simulated rig served by `elphel-sim up`."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from .rig import start_rig, stop_rig


@pytest.fixture(scope="session")
def sim_rig() -> Iterator[dict[str, Any]]:
    """`elphel-sim up --json` on free ports; yields its announcement (urls, token)."""
    proc, announce = start_rig("--seed", "5")
    try:
        yield announce
    finally:
        stderr = stop_rig(proc)
        assert proc.returncode == 0, f"elphel-sim up exited {proc.returncode}: {stderr}"
