"""`keep_freed_memory`: chunk temporaries are reused instead of faulted in again."""

from __future__ import annotations

import subprocess
import sys

import pytest

from elphel_host.parallel import keep_freed_memory

# in a fresh interpreter: page faults of 20 rounds of temporaries
CHURN = """
import resource, sys
import numpy as np
from elphel_host.parallel import keep_freed_memory
if sys.argv[1] == "keep":
    assert keep_freed_memory()
def chunk():
    a = np.ones((2048, 324), dtype=np.float32)  # 2.6 MB, like a chunk's samples
    b = np.ones(10_000_000, dtype=np.float32)  # 40 MB: glibc maps and unmaps it each time
    return float(a[0, 0] + b[0])
chunk()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    chunk()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def faults(mode: str) -> int:
    out = subprocess.run(
        [sys.executable, "-c", CHURN, mode], capture_output=True, text=True, check=True
    )
    return int(out.stdout)


def test_freed_temporaries_are_reused_not_faulted_in_again() -> None:
    if not keep_freed_memory():
        pytest.skip("not glibc: mallopt is not available")
    assert keep_freed_memory()  # once per process, and it stays in effect
    default, kept = faults("default"), faults("keep")
    # 20 rounds of 43 MB: by default every round maps new pages (a fault per page, or per
    # huge page with transparent huge pages: about 12,000 faults here)
    assert default > 1000, default
    assert kept < default / 20, (kept, default)
