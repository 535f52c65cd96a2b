"""A sensor a kernel driver owns, driven through its node's V4L2 controls.

`V4L2Sensor` is the port's `elphel_camd.sensors.base.SensorDriver`: the sequencer asks it
to program a state one frame ahead and it sets the controls that changed. Each frame's
parameters are the values the driver holds, read back after every set (a driver may
round or clamp what it was asked), and in effect for the frames that start after that
set: a frame's driver timestamp (CLOCK_MONOTONIC for most capture drivers) is compared
with the times of the sets, so a set issued late (the stream thread behind the driver)
is not credited to frames already taken. A change another program makes is seen when
the next frame arrives and counted from the frames after it. Its Bayer order is the
node's format after the flips, taken back through them (the metadata applies the flips
again).
"""

from __future__ import annotations

import bisect
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

from elphel_camd.errors import ControlRefusedError, PortDisconnectedError, VideoNodeError
from elphel_camd.i2c.bus import I2CBus
from elphel_camd.params import EXPOSURE, FUNCTIONS, GAINS, PARAMS, WINDOW, check_range
from elphel_camd.sensors.base import SensorDriver, State
from elphel_camd.v4l2.controls import (
    CID_AUTOGAIN,
    CID_EXPOSURE_AUTO,
    CID_HBLANK,
    CID_PIXEL_RATE,
    COLOUR_GAINS,
    EXPOSURE_AUTO_MANUAL,
    UNITY,
    ControlMap,
)
from elphel_camd.v4l2.formats import flipped_bayer
from elphel_camd.v4l2.shape import (
    SHAPE_PARAMS,
    Shape,
    check_window,
    wanted_shape,
    window_limits,
    window_params,
    with_binned_modes,
)
from elphel_camd.v4l2.source import FrameSource, StreamFormat

READBACK_FRAMES = 4096  # frames (and control sets) kept for the frames' metadata
Reshape = Callable[[Shape], StreamFormat]  # stops the stream, sets a shape, starts again
_STATE_NAMES = [n for n, spec in PARAMS.items() if not spec.read_only]


class V4L2Sensor(SensorDriver):
    """Parameters of one port through its node's controls.

    Parameters
    ----------
    source
        Returns the port's node as it is now (a reconnected node is a new object).
    model
        The kernel driver's name (the card or the sensor subdevice), for gain laws.
    period_s
        Returns the port's measured frame period (0 before two frames).
    reshape
        Changes the node's shape between two frames (`elphel_camd.v4l2.stream.PortStream.
        reshape`); without it the window is fixed.
    """

    model = "V4L2"
    i2c_address = 0
    sensor_code = 0
    bayer: ClassVar[str | None] = None  # set per instance: the node's order
    bits = 16
    # Every function is issued one frame ahead; only the window (flips), the gains and the
    # exposure set controls.
    ahead: ClassVar[Mapping[str, tuple[int, int]]] = dict.fromkeys(FUNCTIONS, (1, 1))
    writable: ClassVar[frozenset[str]] = frozenset()  # set per instance: the controls

    def __init__(
        self,
        source: Callable[[], FrameSource],
        *,
        model: str,
        period_s: Callable[[], float],
        reshape: Reshape | None = None,
    ) -> None:
        self._source = source
        self.kernel_model = model
        self._period_s = period_s
        self._reshape = reshape
        node = source()
        self.map = ControlMap(node.controls(), model=model)
        self.shape_options = with_binned_modes(node.shape_options(), model)
        window = self.shape_options.writable if reshape is not None else frozenset()
        self.writable = self.map.offered | window  # type: ignore[misc]
        self._asked: tuple[FrameSource, Shape] | None = None  # the last shape asked of a node
        self.bits = node.stream_format.format.bits  # type: ignore[misc]
        self._written: dict[int, int] = {}
        # (monotonic ns after the set, control values read back then), oldest first
        self._sets: list[tuple[int, dict[int, int]]] = []
        self._frame_times: OrderedDict[int, int] = OrderedDict()  # frame -> timestamp_ns
        # (monotonic ns after a stream restart, the window's parameters from then on)
        self._shapes: list[tuple[int, dict[str, int]]] = []
        self._lock = threading.Lock()
        self._log_values(0, self._read_back())
        self._shapes.append((0, self._window_now()))
        self._update_bayer(self._now_params())

    @classmethod
    def probe(cls, bus: I2CBus, *, bus_name: str) -> SensorDriver | None:
        """A kernel-owned sensor is reached through its node, never found on a bus."""
        return None

    def read_chip_id(self) -> int:
        """0: the kernel reads a kernel-owned sensor's chip id, not the daemon.

        Whether the sensor answers shows in the port's stream state (`V4L2Board.port_status`).
        """
        return 0

    def identity(self) -> dict[str, Any]:
        node = self._source()
        fmt = node.stream_format
        return {
            "model": self.model,
            "kernel_driver": self.kernel_model,
            "node": node.path,
            "chip_id": 0,
            "i2c_address": self.i2c_address,
            "sensor_code": self.sensor_code,
            "bayer": self.bayer,
            "bits": self.bits,
            "format": fmt.format.fourcc,
            "width": fmt.width,
            "height": fmt.height,
            "controls": sorted(self.writable),
            "window": self.shape_options.kind,
        }

    # -- state -----------------------------------------------------------------------------

    def _width(self) -> int:
        return self._source().stream_format.width

    def _timing(self) -> dict[int, int]:
        if not self.map.line_exposure:
            return {}
        return self._source().get_controls([CID_HBLANK, CID_PIXEL_RATE])

    def _read_back(self) -> dict[int, int]:
        return self._source().get_controls(self.map.read_ids())

    def _now_params(self) -> dict[str, int]:
        params = self.map.to_params(self._read_back(), width=self._width())
        params.update(self._window_now())
        return params

    def _window_now(self) -> dict[str, int]:
        return window_params(self._source().shape(), self.shape_options)

    def _update_bayer(self, params: Mapping[str, int]) -> None:
        order = self._source().refresh_format().format.bayer
        if order is not None:
            order = flipped_bayer(
                order, hflip=bool(params.get("FLIPH")), vflip=bool(params.get("FLIPV"))
            )
        self.bayer = order  # type: ignore[misc]

    def init(self) -> None:
        """Manual exposure and gain, so the values asked for are the values used."""
        node = self._source()
        manual = {CID_EXPOSURE_AUTO: EXPOSURE_AUTO_MANUAL, CID_AUTOGAIN: 0}
        present = {c: v for c, v in manual.items() if c in node.controls()}
        if present:
            node.set_controls(present)

    def defaults(self) -> State:
        state = dict.fromkeys(_STATE_NAMES, 0)
        state.update(EXPOS=10_000)
        state.update(dict.fromkeys(COLOUR_GAINS, UNITY))
        state.update(self._now_params())
        state.pop("VEXPOS", None)
        return self.normalize(state, frozenset())

    def normalize(self, state: Mapping[str, int], changed: frozenset[str]) -> State:
        s = dict(state)
        for name in changed & set(COLOUR_GAINS):
            if any(s[g] != s[name] for g in changed & set(COLOUR_GAINS)):
                asked = ", ".join(f"{g}={s[g]}" for g in sorted(changed & set(COLOUR_GAINS)))
                raise ControlRefusedError(
                    name, s[name], f"one gain for all colours on this sensor ({asked})"
                )
            s.update(dict.fromkeys(COLOUR_GAINS, s[name]))
        for name in changed & {"FLIPH", "FLIPV"}:
            check_range(name, s[name], 0, 1)
        if changed & set(SHAPE_PARAMS):
            check_window(s, self.shape_options)
        if changed & self.writable:
            self.map.to_controls(s, width=self._width(), timing=self._timing())
        period = self._period_s()
        s.update(SENSOR=self.sensor_code, COLOR=15, BITS=16)
        s["FP1000S"] = round(1000 / period) if period > 0 else 0
        return s

    def limits(self) -> dict[str, tuple[int, int]]:
        """Each offered parameter's range under the driver's control limits, now."""
        node = self._source()
        found = self.map.limits(width=node.stream_format.width, timing=self._timing())
        window = window_params(node.shape(), self.shape_options)
        found.update(window_limits(window, self.shape_options))
        return found

    def window(self) -> dict[str, int] | None:
        """The crop bounds' size and the edges' step, when the driver crops (else None)."""
        bounds = self.shape_options.crop_bounds
        if bounds is None or "WOI_LEFT" not in self.writable:
            return None
        return {"width": bounds.width, "height": bounds.height, "step": 2}

    def frame_period_s(self, state: Mapping[str, int]) -> float:
        return self._period_s()

    # -- programming and read-back ---------------------------------------------------------

    def program(self, function: str, state: Mapping[str, int]) -> list[str]:
        """Set the controls of a function's parameters that differ from those last set."""
        shaped = self._program_shape(state) if function == WINDOW else []
        names = {WINDOW: ("FLIPH", "FLIPV"), GAINS: COLOUR_GAINS, EXPOSURE: ("EXPOS",)}
        wanted = [n for n in names.get(function, ()) if n in self.writable]
        if not wanted:
            return shaped
        values = self.map.to_controls(state, width=self._width(), timing=self._timing())
        ids = set(self.map.ids_of(wanted))
        changed = {c: v for c, v in values.items() if c in ids and self._written.get(c) != v}
        if not changed:
            return shaped
        node = self._source()
        node.set_controls(changed)
        self._written.update(changed)
        self._log_values(time.monotonic_ns(), self._read_back())
        if function == WINDOW:
            self._update_bayer(state)
        return shaped + wanted

    def _program_shape(self, state: Mapping[str, int]) -> list[str]:
        """Give the node the state's window if it differs: the stream restarts.

        A shape is asked of a node once: a driver that adjusts it (or refuses it) is not
        asked again until the window or the node (after a reconnect) changes; the frames'
        metadata records what the driver set.
        """
        if self._reshape is None or not self.shape_options.writable:
            return []
        node = self._source()
        current = node.shape()
        wanted = wanted_shape(state, self.shape_options, current)
        if wanted == current or self._asked == (node, wanted):
            return []
        self._asked = (node, wanted)
        try:
            fmt = self._reshape(wanted)
        except (ControlRefusedError, VideoNodeError) as e:
            raise ControlRefusedError(
                "WOI_WIDTH", state["WOI_WIDTH"], f"a window the driver of {node.path} takes: {e}"
            ) from e
        self.bits = fmt.format.bits  # type: ignore[misc]
        window = self._window_now()
        with self._lock:  # frames from the restarted stream are taken after now
            self._shapes.append((time.monotonic_ns(), window))
            del self._shapes[:-READBACK_FRAMES]
        self._update_bayer(state)
        return [n for n in SHAPE_PARAMS if n in self.writable]

    def _log_values(self, when_ns: int, values: dict[int, int]) -> None:
        """Values the driver holds from ``when_ns`` on (a set, or a change seen)."""
        with self._lock:
            if self._sets and self._sets[-1][1] == values:
                return
            self._sets.append((when_ns, values))
            del self._sets[:-READBACK_FRAMES]

    def note_frame(self, frame: int, timestamp_ns: int) -> None:
        """Remember when a frame was taken (its driver timestamp), for its metadata."""
        with self._lock:
            self._frame_times[frame] = timestamp_ns
            while len(self._frame_times) > READBACK_FRAMES:
                self._frame_times.popitem(last=False)

    def record(self, frame: int, timestamp_ns: int) -> None:
        """A frame arrived: note its time and read the controls back.

        A change another program made shows here; it counts from the frames that start
        after now.
        """
        self.note_frame(frame, timestamp_ns)
        try:
            values = self._read_back()
        except (PortDisconnectedError, OSError):
            return
        self._log_values(time.monotonic_ns(), values)

    def values_at(self, frame: int) -> dict[int, int] | None:
        """The control values in effect for a frame that arrived (None: unknown)."""
        with self._lock:
            taken = self._frame_times.get(frame)
            times = [t for t, _ in self._sets]
            k = bisect.bisect_right(times, taken) if taken is not None else 0
            return dict(self._sets[k - 1][1]) if k else None

    def actual_gains(self, state: Mapping[str, int]) -> dict[str, int]:
        """The parameters the driver applied to the state's frame (EXPOS, gains, flips).

        Empty for a frame that has not arrived: its parameters are those asked for.
        """
        frame = state.get("FRAME", -1)
        values = self.values_at(frame)
        if values is None:
            return {}
        params = self.map.to_params(values, width=self._width())
        params.update(self._window_at(frame))
        return params

    def _window_at(self, frame: int) -> dict[str, int]:
        """The window's parameters of a frame that arrived (the last restart before it)."""
        with self._lock:
            taken = self._frame_times.get(frame, 0)
            times = [t for t, _ in self._shapes]
            k = bisect.bisect_right(times, taken)
            return dict(self._shapes[max(k - 1, 0)][1])
