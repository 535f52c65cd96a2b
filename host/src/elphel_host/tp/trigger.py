"""One common trigger for the four ports of a quad capture: what to change, staged, restored.

Every port goes to snapshot mode (``TRIG`` 4; 20, snapshot with GRR, stays) on the
master's trigger (the same ``TRIG_MASTER``, no delay or decimation, ``TRIG_PERIOD`` on the
master), inside the camera's ``staged``, so the previous settings come back afterwards,
even after an error; the trigger is restored last, once no port waits for it any more.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator, Mapping, Sequence

from elphel_host.camera.protocol import CameraInterface
from elphel_host.errors import QuadCaptureTimeout

TRIG_SNAPSHOT = 4  # TRIG bit: the sensor waits for a trigger
TRIG_PERIOD_MIN_REPEAT = 256  # TRIG_PERIOD below this stops the trigger or fires once
TICKS_PER_MS = 100_000  # TRIG_PERIOD counts 10 ns
# Slow enough that the daemon's ring buffer (64 frames) holds the set for half a minute
# while four full frames are fetched, even from a simulator rendering them.
DEFAULT_TRIGGER_PERIOD_MS = 500.0


def trigger_ticks(period_ms: float) -> int:
    """``TRIG_PERIOD`` (10 ns ticks) of a repeating trigger period in milliseconds."""
    ticks = round(period_ms * TICKS_PER_MS)
    if not ticks >= TRIG_PERIOD_MIN_REPEAT:
        raise ValueError(
            f"trigger period {period_ms} ms; allowed: >= {TRIG_PERIOD_MIN_REPEAT / TICKS_PER_MS} ms"
        )
    return ticks


def choose_trigger(
    before: Mapping[int, Mapping[str, int]],
    ports: Sequence[int],
    period_ms: float | None,
) -> tuple[int, int]:
    """The master port and the ``TRIG_PERIOD`` of the common trigger.

    The master is a port that names itself master (so ``TRIG_MASTER`` stays as it is),
    else the first port. The period is ``period_ms`` if given, else the master's
    repeating period if it has one, else `DEFAULT_TRIGGER_PERIOD_MS`.
    """
    master = next((q for q in ports if before[q]["TRIG_MASTER"] == q), ports[0])
    if period_ms is not None:
        return master, trigger_ticks(period_ms)
    if before[master]["TRIG_PERIOD"] >= TRIG_PERIOD_MIN_REPEAT:
        return master, before[master]["TRIG_PERIOD"]
    return master, trigger_ticks(DEFAULT_TRIGGER_PERIOD_MS)


def trigger_changes(
    before: Mapping[int, Mapping[str, int]], *, master: int, period: int
) -> tuple[dict[int, dict[str, int]], dict[int, dict[str, int]]]:
    """What differs from snapshot mode on the master's trigger.

    Returns the master's common trigger (``TRIG_PERIOD``, and ``TRIG_MASTER`` if it must
    name itself) and, per port, the trigger mode, master, delay and decimation.
    """
    now = before[master]
    trigger = {"TRIG_MASTER": master, "TRIG_PERIOD": period}
    common = {k: v for k, v in trigger.items() if now.get(k) != v}
    ports: dict[int, dict[str, int]] = {}
    for p, now in before.items():
        want = {
            "TRIG": now["TRIG"] if now["TRIG"] & TRIG_SNAPSHOT else TRIG_SNAPSHOT,
            "TRIG_MASTER": master,
            "TRIG_DELAY": 0,
            "TRIG_DECIMATE": 0,
        }
        diff = {k: v for k, v in want.items() if now.get(k) != v and k not in common}
        if diff:
            ports[p] = diff
    return ({master: common} if common else {}), ports


@contextlib.contextmanager
def on_common_trigger(
    camera: CameraInterface, before: Mapping[int, Mapping[str, int]], *, master: int, period: int
) -> Iterator[dict[int, int]]:
    """Every port in snapshot mode on the master's trigger; the old settings back after.

    The trigger starts before any port waits for it, and on the way back it is restored
    only once every port runs as before: a port still in snapshot mode when the trigger
    stops would wait forever, and its own restore with it. Yields, per port changed, the
    frame from which the change is in effect.
    """
    common, ports = trigger_changes(before, master=master, period=period)
    with camera.staged(common) as started:
        try:
            with camera.staged(ports) as applied:
                yield {p: a.frame for p, a in {**started, **applied}.items()}
        except BaseException as e:
            late = _wait_restored(camera, before, ports, period)
            if late:
                e.add_note(late)
            raise
        late = _wait_restored(camera, before, ports, period)
        if late:
            raise QuadCaptureTimeout(late)


def _wait_restored(
    camera: CameraInterface,
    before: Mapping[int, Mapping[str, int]],
    changed: Mapping[int, Mapping[str, int]],
    period: int,
) -> str:
    """Wait until the ports' previous settings are in effect again; say which are not."""
    deadline = time.monotonic() + 10.0 + 4 * period / 1e8  # a restore needs frames
    pending = {p: {k: before[p][k] for k in keys} for p, keys in changed.items()}
    while pending:
        for p in list(pending):
            now = camera.params(p)
            if all(now.get(k) == v for k, v in pending[p].items()):
                del pending[p]
        if not pending or time.monotonic() > deadline:
            break
        time.sleep(min(0.05, period / 4e8))
    if not pending:
        return ""
    return "previous trigger settings not back in effect on port(s) " + ", ".join(
        f"{p} ({', '.join(f'{k}={v}' for k, v in want.items())})" for p, want in pending.items()
    )
