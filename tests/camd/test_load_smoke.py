"""bench/load.py for ~30 s: one JSON object, no server errors, the stalled listener dropped.

The full run (600 s) is for the report; here the mix runs briefly with the default 50
clients and 20 listeners, and a per-stream queue of 32 events so that the stalled
listener falls behind within the run. Latency targets are not asserted (a shared
machine), the invariants are.
"""

import json
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "bench" / "load.py"


def test_load_smoke():
    options = ["--duration", "30", "--idle-captures", "1", "--event-queue", "32"]
    done = subprocess.run(
        [sys.executable, str(BENCH), *options],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.strip().splitlines()
    assert len(lines) == 1
    result = json.loads(lines[0])
    assert result["clients"]["listeners_reading"] == 19
    endpoints = result["endpoints"]
    for name in ("GET params", "PATCH params", "POST capture (full)", "POST capture (ring)"):
        assert endpoints[name]["count"] > 0, name
    assert endpoints["PATCH params"]["statuses"].get("200", 0) > 50
    assert result["errors"]["5xx"] == 0, result["errors"]
    assert result["errors"]["unexpected_4xx"] == 0, result["errors"]
    assert result["errors"]["transport"] == 0, result["errors"]
    events = result["events"]
    assert events["stalled_listener_dropped"] is True
    assert events["readers_with_drops"] == 0 and events["readers_ended_early"] == []
    assert events["lag_samples"] > 0
    assert result["frames_dropped"] == {"ring_misses": 0, "event_gaps": 0}
    assert set(result["rss_mb"]) == {"start", "at_6_s", "end"}
    assert result["ratios"]["capture_full_p99_vs_idle"] is not None
