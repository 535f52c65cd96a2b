"""Virtual time for the simulated board, paced against real time by a scale factor."""

from __future__ import annotations

import select
import threading
import time


class SimReset(BaseException):
    """Raised inside the firmware thread to emulate a reset of the board."""


class SimShutdown(BaseException):
    """Raised inside the firmware thread when the simulator stops."""


class VirtualClock:
    """Microsecond clock advanced by the firmware's own calls (sleep, pin reads, waits).

    Virtual time runs at most ``time_scale`` times faster than real time: when the
    simulation is ahead of that pace it sleeps; when it falls behind (CPU-bound) it
    re-anchors instead of racing to catch up. The hooks in `checks` (watchdog, reset
    requests, shutdown) run after every wait and whenever `CHECK_EVERY_US` of virtual
    time has passed; pacing and checks are not worth their cost on each of the many
    microsecond advances a step pulse or a caliper frame makes.
    """

    CHECK_EVERY_US = 200

    def __init__(self, time_scale: float = 1.0) -> None:
        if time_scale <= 0:
            raise ValueError(f"time_scale {time_scale} must be > 0")
        self.time_scale = time_scale
        self.now_us = 0
        self._anchor_real = time.monotonic()
        self._anchor_us = 0
        self._lock = threading.Lock()
        self.checks: list[object] = []
        self._checked_us = 0

    def _real_for(self, t_us: int) -> float:
        return self._anchor_real + (t_us - self._anchor_us) / 1e6 / self.time_scale

    def _pace(self) -> None:
        ahead = self._real_for(self.now_us) - time.monotonic()
        if ahead > 0.002:
            time.sleep(ahead)
        elif ahead < -0.05:
            self._anchor_real = time.monotonic()
            self._anchor_us = self.now_us

    def advance(self, dt_us: int) -> None:
        """Let dt_us of virtual time pass (dt_us >= 0)."""
        if dt_us > 0:
            self.now_us += int(dt_us)
        if self.now_us - self._checked_us >= self.CHECK_EVERY_US:
            self._pace()
            self._run_checks()

    def _run_checks(self) -> None:
        self._checked_us = self.now_us
        for check in self.checks:
            check()  # type: ignore[operator]

    def wait_io(self, timeout_us: int, fds: list[int]) -> list[int]:
        """Wait for readable real fds for up to timeout_us virtual; return the ready ones."""
        self._pace()
        deadline_us = self.now_us + max(0, timeout_us)
        real_timeout = max(0.0, self._real_for(deadline_us) - time.monotonic())
        ready, _, _ = select.select(fds, [], [], real_timeout) if fds else ([], [], [])
        if not ready:
            self.now_us = deadline_us
        else:
            elapsed_us = int(
                (time.monotonic() - self._real_for(self.now_us)) * 1e6 * self.time_scale
            )
            self.now_us = min(deadline_us, self.now_us + max(1, elapsed_us))
        self._run_checks()
        return ready
