"""A simulated board's virtual time run against the wall clock, in a thread.

Tests step virtual time themselves (`SimCameraBoard.sim_advance`); a served rig runs it
with a `FrameClock`, which starts each frame when its start time comes (``time_scale``
times real time) and otherwise sleeps, at most 50 ms at a time so that stopping is quick.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Protocol


class Stepped(Protocol):
    def next_start_s(self) -> float: ...

    def sim_step(self) -> object: ...


class FrameClock:
    """Starts the frames of ``board`` in real time until `stop`.

    Parameters
    ----------
    board
        Gives the virtual time of the next frame start and starts it.
    now_s
        The virtual time now (the wall clock's origin).
    time_scale
        Virtual seconds per wall-clock second.
    """

    def __init__(self, board: Stepped, *, now_s: float, time_scale: float = 1.0) -> None:
        self._stop = threading.Event()
        origin_wall, origin_sim = time.monotonic(), now_s

        def run() -> None:
            while not self._stop.is_set():
                due = board.next_start_s()
                wait = (due - origin_sim) / time_scale - (time.monotonic() - origin_wall)
                if math.isinf(wait) or wait > 0:
                    self._stop.wait(0.05 if math.isinf(wait) else min(wait, 0.05))
                    continue
                board.sim_step()

        self._thread = threading.Thread(target=run, name="sim-frame-clock", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
