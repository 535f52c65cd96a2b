"""Fixtures of the integration tests: a simulated rig served by `elphel-sim up`."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from .rig import running_rig


@pytest.fixture(scope="session")
def sim_rig() -> Iterator[dict[str, Any]]:
    """`elphel-sim up --json` on free ports; yields its announcement (urls, token)."""
    with running_rig("--seed", "5") as announce:
        yield announce
