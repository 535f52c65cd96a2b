"""Frame-ahead scheduling of parameter changes (Elphel's frame pages, in Python).

Each port keeps the parameter state in effect now and the changes requested for future
frames. A change for frame N is accepted only if every register write it needs can still
be issued in time: ``this_frame + latency < N < this_frame + 15`` (else `FrameTooLateError`
or `FrameTooEarlyError`, and nothing changes). On every frame sync the sequencer asks the
driver, function by function, for the registers of the frame that function's latency
targets and writes those that changed; the image of frame N is then formed with exactly
the parameters requested for N.
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping

from elphel_camd.errors import (
    FrameNotAvailableError,
    FrameTooEarlyError,
    FrameTooLateError,
    I2CError,
    UnsupportedError,
)
from elphel_camd.params import FUNCTIONS, check_names, functions_of
from elphel_camd.sensors.base import SensorDriver, State

log = logging.getLogger(__name__)

# Writes can target the current frame + 1 .. + 14 (16 hardware frame pages, Elphel).
MAX_AHEAD = 14
# Parameters of past frames kept for their metadata. A frame is looked up after it was
# formed: the simulator renders a full frame in seconds while a small window runs at
# 100-200 fps, so 256 frames were gone by then ("no longer kept"). A state is ~25 ints.
HISTORY_FRAMES = 4096

# Called for functions the board handles (trigger sequencer, photo-finish) with the state.
BoardProgram = Callable[[str, Mapping[str, int]], None]


class PortSequencer:
    """Parameters of one port, now and for the next 14 frames.

    Parameters
    ----------
    port
        Port number (for messages).
    driver
        The port's sensor driver.
    board_program
        Called as ``board_program(function, state)`` for every function, with the state
        of the frame it targets, so the board can program what is not in the sensor.
    """

    def __init__(
        self, port: int, driver: SensorDriver, *, board_program: BoardProgram | None = None
    ) -> None:
        self.port = port
        self.driver = driver
        self.board_program = board_program
        self.lock = threading.RLock()
        self.this_frame = 0
        self.this_timestamp_ns = 0
        self._now: State = driver.defaults()
        self._pending: dict[int, dict[str, int]] = {}
        self._history: OrderedDict[int, State] = OrderedDict()
        self.errors: list[str] = []

    # -- state -----------------------------------------------------------------------------

    def state_at(self, frame: int) -> State:
        """Parameters in effect for a frame (past frames from the history)."""
        with self.lock:
            if frame < self.this_frame:
                try:
                    return dict(self._history[frame])
                except KeyError:
                    raise FrameNotAvailableError(
                        f"port {self.port}: parameters of frame {frame} are no longer kept "
                        f"(oldest {next(iter(self._history), self.this_frame)})"
                    ) from None
            state = dict(self._now)
            for target in sorted(self._pending):
                if target > frame:
                    break
                # Each change is normalised with what it changed (VEXPOS rules over EXPOS).
                changes = self._pending[target]
                state = self.driver.normalize({**state, **changes}, frozenset(changes))
            return self._normalized(state, frozenset(), frame)

    def _normalized(self, state: Mapping[str, int], changed: frozenset[str], frame: int) -> State:
        out = self.driver.normalize(state, changed)
        out["FRAME"] = frame
        return out

    def latency(self, names: Mapping[str, int], state: Mapping[str, int]) -> int:
        fns = functions_of(names) & set(self.driver.ahead)
        return max((self.driver.latency(fn, state) for fn in fns), default=1)

    # -- requests --------------------------------------------------------------------------

    def check(self, changes: Mapping[str, int]) -> None:
        """Raise as `request` would for these changes at the earliest frame; change nothing."""
        with self.lock:
            self._plan(changes, None, None)

    def request(
        self, changes: Mapping[str, int], *, frame: int | None = None, ahead: int | None = None
    ) -> int:
        """Schedule changes; return the frame at which they are in effect.

        Parameters
        ----------
        changes
            Parameter names and values; all are applied or none.
        frame
            Absolute target frame.
        ahead
            Target relative to the current frame (``frame=+k``).
            With neither, the earliest frame the changes can reach; both are refused
            (UnsupportedError).
        """
        with self.lock:
            target, merged = self._plan(changes, frame, ahead)
            self._pending = merged
            return target

    def _plan(
        self, changes: Mapping[str, int], frame: int | None, ahead: int | None
    ) -> tuple[int, dict[int, dict[str, int]]]:
        if frame is not None and ahead is not None:
            raise UnsupportedError("give frame or ahead, not both")
        check_names(changes)
        self.driver.check_writable(changes)
        now = self.this_frame
        latency = max(
            self.latency(changes, self.state_at(now)),
            self.latency(changes, {**self.state_at(now), **changes}),
        )
        earliest, latest = now + latency + 1, now + MAX_AHEAD
        relative = earliest if ahead is None else now + ahead
        target = relative if frame is None else frame
        if target < earliest:
            raise FrameTooLateError(
                f"port {self.port}: frame {target} is too late for "
                f"{', '.join(sorted(changes))} (latency {latency}); current frame {now}, "
                f"allowed frames {earliest}..{latest}",
                frame=target,
                this_frame=now,
                earliest=earliest,
                latest=latest,
            )
        if target > latest:
            raise FrameTooEarlyError(
                f"port {self.port}: frame {target} is too far ahead; current frame {now}, "
                f"allowed frames {earliest}..{latest}",
                frame=target,
                this_frame=now,
                earliest=earliest,
                latest=latest,
            )
        # All-or-nothing: the target frame and every later scheduled frame must stay valid.
        merged = dict(self._pending)
        merged[target] = {**merged.get(target, {}), **changes}
        state: State = dict(self._now)
        for t in sorted(merged):
            if t < target:
                state = self.driver.normalize({**state, **merged[t]}, frozenset(merged[t]))
            else:
                state = self._normalized({**state, **merged[t]}, frozenset(merged[t]), t)
        return target, merged

    def schedule(self) -> tuple[State, dict[int, dict[str, int]]]:
        """The state now and the scheduled changes (for `restore_schedule`)."""
        with self.lock:
            return dict(self._now), {t: dict(c) for t, c in self._pending.items()}

    def restore_schedule(self, saved: tuple[State, dict[int, dict[str, int]]]) -> None:
        """Take back the changes requested since `schedule` (the hardware was not written)."""
        with self.lock:
            self._now, self._pending = dict(saved[0]), {t: dict(c) for t, c in saved[1].items()}
            if "FRAME" in self._now:
                self._now["FRAME"] = self.this_frame

    def flush(self) -> None:
        """Apply every scheduled change now (boards without frame syncs)."""
        with self.lock:
            for target in sorted(self._pending):
                changes = self._pending.pop(target)
                self._now = self._normalized({**self._now, **changes}, frozenset(changes), target)
            for fn in FUNCTIONS:
                self._program(fn, self._now)

    # -- frame sync ------------------------------------------------------------------------

    def start(self) -> None:
        """Initialise the sensor and program the default state at once."""
        with self.lock:
            self.driver.init()
            for fn in FUNCTIONS:
                self._program(fn, self._now)

    def _program(self, function: str, state: Mapping[str, int]) -> None:
        if function in self.driver.ahead:
            self.driver.program(function, state)
        if self.board_program is not None:
            self.board_program(function, state)

    def on_frame_sync(self, frame: int, timestamp_ns: int = 0) -> None:
        """Frame ``frame`` started: fold its changes in, issue the writes now due."""
        with self.lock:
            self.this_timestamp_ns = timestamp_ns
            for target in sorted(t for t in self._pending if t <= frame):
                changes = self._pending.pop(target)
                self._now = self._normalized({**self._now, **changes}, frozenset(changes), target)
            self.this_frame = frame
            self._now["FRAME"] = frame
            self._history[frame] = dict(self._now)
            while len(self._history) > HISTORY_FRAMES:
                self._history.popitem(last=False)
            for fn in FUNCTIONS:
                if fn not in self.driver.ahead and self.board_program is None:
                    continue
                target_state = self.state_at(frame + self.driver.latency(fn, self._now))
                try:
                    self._program(fn, target_state)
                except I2CError as e:
                    # Reported, not fatal: the next frame sync retries the same writes.
                    self.errors.append(str(e))
                    log.error("%s", e)
