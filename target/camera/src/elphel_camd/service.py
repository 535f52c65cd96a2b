"""The camera service: the daemon's view of a board, what the REST API calls.

`CameraService` detects the sensor on every port of a `Board`, runs a frame sequencer per
port, keeps the common trigger settings in sync across ports, restores and saves the
accepted parameters (`ParamStore`), captures frames with their metadata (through its
`FrameCapture`, in ``capture.py``), gives raw register access and reports health. A PATCH
of parameters enters here (`CameraService.set_params`) and leaves through the port's
`PortSequencer`.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Generator, Mapping
from functools import partial
from typing import Any

from elphel_camd import __version__
from elphel_camd.boards.base import Board, Frame
from elphel_camd.capture import CapturePool, FrameCapture
from elphel_camd.errors import (
    CameraError,
    I2CError,
    ParameterRangeError,
    PortError,
    PortI2CError,
    RegisterNotFoundError,
    SensorNotFoundError,
    StateWriteError,
    UnsupportedError,
)
from elphel_camd.events import EventHub
from elphel_camd.params import COMMON_TRIGGER_PARAMS, PARAMS
from elphel_camd.sensors import SensorDriver, detect, register_file
from elphel_camd.sensors.registers import Access, Register
from elphel_camd.sequencer import MAX_AHEAD, PortSequencer
from elphel_camd.store import ParamStore

log = logging.getLogger(__name__)

# Parameters that need a part of the board beyond the sensor (a board capability).
_NEEDS = {
    "TRIG_PERIOD": "trigger",
    "TRIG_DELAY": "trigger",
    "TRIG_DECIMATE": "trigger",
    "PF_HEIGHT": "photofinish",
}


class CameraService:
    """The daemon's view of a board: sensors, their sequencers, capture with metadata.

    Parameters
    ----------
    board
        The board.
    events
        Where frames, parameter changes and errors are published (a new hub if None).
    store
        Where accepted parameters are saved; the saved ones are restored here, before the
        first frame sync. None keeps nothing.
    """

    def __init__(
        self, board: Board, *, events: EventHub | None = None, store: ParamStore | None = None
    ) -> None:
        self.board = board
        self.events = events if events is not None else EventHub()
        self.store = store
        self.sensors: dict[int, SensorDriver | None] = {
            port: detect(bus, bus_name=f"port {port}") for port, bus in board.buses().items()
        }
        # Sensors the board drives itself (a kernel driver's, through V4L2 controls; a
        # Lepton without its CCI).
        board_sensors = getattr(board, "sensors", None)
        if board_sensors is not None:
            self.sensors.update(board_sensors())
        self.sequencers: dict[int, PortSequencer] = {}
        for port, driver in self.sensors.items():
            if driver is not None:
                seq = PortSequencer(port, driver, board_program=partial(board.program, port))
                seq.start()
                self.sequencers[port] = seq
        self.started_ns = time.time_ns()
        self._errors_seen = {port: 0 for port in self.sequencers}
        # Saved files must end at the newest state: versions order the writes of a port.
        self._versions = dict.fromkeys(self.sequencers, 0)
        self._saved = dict.fromkeys(self.sequencers, 0)
        self._save_locks = {port: threading.Lock() for port in self.sequencers}
        if store is not None:
            self._restore(store)
        self.capture_pool = CapturePool()
        self.frames = FrameCapture(board, self.sequencers, sensor=self.sensor, params=self.params)
        board.on_frame_sync(self._frame_sync)
        on_lost = getattr(board, "on_frame_lost", None)
        if on_lost is not None:  # lost frames still move the schedule on (the v4l2 board)
            on_lost(self._frame_lost)
        on_event = getattr(board, "on_event", None)
        if on_event is not None:  # a board's own news: port states, lost frames
            on_event(self.events.publish)

    def _frame_lost(self, port: int, frame: int) -> None:
        seq = self.sequencers.get(port)
        if seq is not None:
            seq.on_frame_sync(frame)

    def _frame_sync(self, port: int, frame: int, timestamp_ns: int) -> None:
        seq = self.sequencers.get(port)
        if seq is None:
            return
        seq.on_frame_sync(frame, timestamp_ns)
        self.frames.on_frame_sync(port, frame)
        errors = seq.errors
        if len(errors) > self._errors_seen[port]:
            for message in errors[self._errors_seen[port] :]:
                self.events.publish(
                    "error", {"port": port, "frame": frame, "error": "i2c", "detail": message}
                )
            # The sequencer only appends; keep its list short on a long-running daemon.
            del errors[:-16]
            self._errors_seen[port] = len(errors)
        self.events.publish("frame", {"port": port, "frame": frame, "timestamp_ns": timestamp_ns})

    # -- persistence -----------------------------------------------------------------------

    def _persistent(self, port: int) -> dict[str, int]:
        """What to save of a port: its writable parameters once every scheduled change is in.

        VEXPOS follows from EXPOS; common trigger settings are saved by the master port.
        """
        seq = self.sequencers[port]
        state = seq.state_at(seq.this_frame + MAX_AHEAD)
        keep = set(seq.driver.writable) - {"VEXPOS"}
        if state.get("TRIG_MASTER", port) != port:
            keep -= set(COMMON_TRIGGER_PARAMS)
        return {k: v for k, v in state.items() if k in keep}

    def _save(self, port: int, version: int, params: dict[str, int]) -> None:
        if self.store is None:
            return
        with self._save_locks[port]:
            if version <= self._saved[port]:
                return  # a newer state of this port is on disk already
            self.store.save(port, self.sensors[port].model, params)  # type: ignore[union-attr]
            self._saved[port] = version

    def _restore(self, store: ParamStore) -> None:
        common: dict[str, int] = {}
        for port, seq in self.sequencers.items():
            saved = store.load(port, seq.driver.model)
            if not saved:
                continue
            values = {
                k: v
                for k, v in saved.items()
                if k in seq.driver.writable and k not in COMMON_TRIGGER_PARAMS
            }
            if saved.get("TRIG_MASTER", port) == port:
                common.update({k: v for k, v in saved.items() if k in COMMON_TRIGGER_PARAMS})
            try:
                with seq.lock:
                    seq.request(values)
                    seq.flush()
            except (CameraError, ValueError) as e:
                log.error("port %d: saved parameters not restored: %s", port, e)
                continue
            log.info("port %d: restored %d saved parameters", port, len(values))
        if common:
            try:
                for seq in self.sequencers.values():
                    seq.check(common)
                for seq in self.sequencers.values():
                    with seq.lock:
                        seq.request(common)
                        seq.flush()
            except (CameraError, ValueError) as e:
                log.error("saved common trigger settings not restored: %s", e)

    @property
    def saves_wait_for_disk(self) -> bool:
        """Whether each accepted change is flushed to the disk before it is answered."""
        return self.store is not None and self.store.sync_each

    @property
    def scheduled(self) -> bool:
        """Whether changes can be scheduled on frames (the board delivers frame syncs)."""
        return "frames" in self.board.capabilities

    def sensor(self, port: int) -> SensorDriver:
        """The driver on a port.

        Raises PortError for a port the board lacks, SensorNotFoundError for an empty one.
        """
        if port not in self.sensors:
            raise PortError(f"port {port} does not exist; ports: {sorted(self.sensors)}")
        driver = self.sensors[port]
        if driver is None:
            raise SensorNotFoundError(f"port {port}: no sensor detected")
        return driver

    def sequencer(self, port: int) -> PortSequencer:
        """The frame sequencer of a port (errors as `sensor`)."""
        self.sensor(port)
        return self.sequencers[port]

    def info(self) -> dict[str, Any]:
        """Board, daemon version, capabilities, and each port with its sensor's identity."""
        ports = []
        for port, driver in sorted(self.sensors.items()):
            entry: dict[str, Any] = {"port": port, "sensor": None}
            if driver is not None:
                entry["sensor"] = driver.identity()
                entry["frame"] = self.sequencers[port].this_frame
            status = getattr(self.board, "port_status", None)
            if status is not None:
                entry["stream"] = status(port)
            ports.append(entry)
        return {
            "board": self.board.name,
            "daemon": "elphel-camd",
            "version": __version__,
            "capabilities": sorted(self.board.capabilities),
            "ports": ports,
        }

    # -- parameters ------------------------------------------------------------------------

    def params(self, port: int, *, frame: int | None = None) -> dict[str, int]:
        """The parameters in effect now (or for a recent or scheduled frame)."""
        seq = self.sequencer(port)
        state = seq.state_at(seq.this_frame if frame is None else frame)
        state.update(self.sensor(port).actual_gains(state))
        return {k: v for k, v in state.items() if k in PARAMS}

    def param_locks(self, port: int, changes: Mapping[str, int]) -> list[threading.RLock]:
        """The port locks `set_params` holds for these changes, in the order it takes them.

        A caller that takes them first (and reads the answer under them) sees no other
        write in between. Raises as `sensor` for a port without one.
        """
        return [self.sequencers[p].lock for p in self._ports_held(port, changes)]

    def _ports_held(self, port: int, changes: Mapping[str, int]) -> list[int]:
        """One port per change; a change of the common trigger holds every port, in order."""
        self.sequencer(port)
        common = any(name in changes for name in COMMON_TRIGGER_PARAMS)
        return sorted(self.sequencers) if common else [port]

    def set_params(
        self,
        port: int,
        changes: Mapping[str, int],
        *,
        frame: int | None = None,
        ahead: int | None = None,
    ) -> int:
        """Apply changes all-or-nothing; return the frame at which they are in effect.

        Common trigger settings (TRIG_PERIOD) are accepted only on the TRIG_MASTER port and
        copied to the other ports, as Elphel's drivers do. ``frame`` (absolute) and
        ``ahead`` (relative) pick the target frame as in `PortSequencer.request`.
        """
        ports = self._ports_held(port, changes)
        self._refuse_unavailable(changes, frame, ahead)
        common = {k: v for k, v in changes.items() if k in COMMON_TRIGGER_PARAMS}
        with contextlib.ExitStack() as held:
            for p in ports:
                held.enter_context(self.sequencers[p].lock)
            if common:
                self._check_common(port, changes, common)
            target = self._schedule(port, ports, changes, common, frame, ahead)
        self.events.publish("params", {"port": port, "frame": target, "changes": dict(changes)})
        return target

    def _refuse_unavailable(
        self, changes: Mapping[str, int], frame: int | None, ahead: int | None
    ) -> None:
        """Refuse what this board cannot do: missing hardware, frames without frame syncs."""
        for name, value in changes.items():
            need = _NEEDS.get(name)
            if need and value and need not in self.board.capabilities:
                raise UnsupportedError(f"{name}: board {self.board.name} has no {need} hardware")
        if not self.scheduled and (frame is not None or ahead is not None):
            raise UnsupportedError(
                f"board {self.board.name} has no frame syncs: changes apply at once, "
                "frame= and ahead= are not available"
            )
        master_port = changes.get("TRIG_MASTER")
        if master_port is not None and master_port not in self.sequencers:
            have = ", ".join(map(str, sorted(self.sequencers)))
            raise ParameterRangeError("TRIG_MASTER", master_port, f"a port with a sensor: {have}")

    def _check_common(
        self, port: int, changes: Mapping[str, int], common: Mapping[str, int]
    ) -> None:
        """Refuse common trigger settings off the master port, or that another port refuses."""
        seq = self.sequencers[port]
        master = changes.get("TRIG_MASTER", seq.state_at(seq.this_frame)["TRIG_MASTER"])
        if master != port:
            raise ParameterRangeError(
                "TRIG_PERIOD", common["TRIG_PERIOD"], f"set on the master port {master}"
            )
        for other, other_seq in self.sequencers.items():  # check first: all ports or none
            if other != port:
                other_seq.check(common)

    def _schedule(
        self,
        port: int,
        ports: list[int],
        changes: Mapping[str, int],
        common: Mapping[str, int],
        frame: int | None,
        ahead: int | None,
    ) -> int:
        """Schedule and save the changes under the held locks; all or nothing.

        A change that cannot be saved (disk full, read-only state directory) or written
        (no frame syncs: programmed at once) is taken back and refused.
        """
        seq = self.sequencers[port]
        before = {p: self.sequencers[p].schedule() for p in ports}
        try:
            target = seq.request(changes, frame=frame, ahead=ahead)
            for p in ports:
                if p != port:
                    self.sequencers[p].request(common)
            if not self.scheduled:
                seq.flush()
            for p in ports:
                self._versions[p] += 1
                self._save(p, self._versions[p], self._persistent(p))
        except (StateWriteError, I2CError) as e:
            self._take_back(port, before)
            if isinstance(e, I2CError):
                raise PortI2CError(port, e) from e
            raise
        return target

    def _take_back(self, port: int, before: Mapping[int, Any]) -> None:
        """Restore the schedules of ``before``; a board without frame syncs is rewritten."""
        for p, schedule in before.items():
            self.sequencers[p].restore_schedule(schedule)
        if not self.scheduled:
            try:
                self.sequencers[port].flush()
            except I2CError as again:
                log.error("port %d: previous state not written back: %s", port, again)

    # -- frames ----------------------------------------------------------------------------

    def capture(self, port: int, *, frame: int | None = None) -> tuple[Frame, dict[str, Any]]:
        """The next frame of a port (or a recent one) and its metadata."""
        return self.frames.capture(port, frame=frame)

    def burst(
        self, port: int, count: int, *, frame: int | None = None
    ) -> Generator[tuple[Frame, dict[str, Any]], None, None]:
        """``count`` consecutive frames of a port, each held until taken (`FrameCapture.burst`)."""
        return self.frames.burst(port, count, frame=frame)

    # -- raw registers ---------------------------------------------------------------------

    def register(self, port: int, address: int) -> Register:
        """The register table entry at an address (ParameterRangeError if none)."""
        table = register_file(self.sensor(port)).table
        register = table.at(address)
        if register is None:
            known = ", ".join(f"0x{r.address:02x}" for r in table)
            raise RegisterNotFoundError(
                "address", f"0x{address:x}", f"a {table.model} register address: {known}"
            )
        return register

    def read_register(self, port: int, address: int) -> tuple[Register, int]:
        """Read a raw register now; its table entry and value."""
        register = self.register(port, address)
        if register.access is Access.WO:
            raise ParameterRangeError(register.name, f"0x{address:x}", "a readable register")
        seq = self.sequencer(port)
        with seq.lock:
            return register, register_file(seq.driver).read(register.name)

    def write_register(self, port: int, address: int, value: int) -> Register:
        """Write a raw register, checked against the table (bypasses the sequencer)."""
        register = self.register(port, address)
        if register.access is Access.RO:
            raise ParameterRangeError(register.name, value, "nothing: the register is read-only")
        if not register.minimum <= value <= register.limit:
            raise ParameterRangeError(register.name, value, f"{register.minimum}..{register.limit}")
        seq = self.sequencer(port)
        with seq.lock:
            register_file(seq.driver).write(register.name, value)
        self.events.publish(
            "params", {"port": port, "frame": seq.this_frame, "register": register.name}
        )
        return register

    # -- health ----------------------------------------------------------------------------

    def health(self) -> dict[str, Any]:
        """Each port's sensor answering its chip id now; the first I2C error, if any."""
        ports: list[dict[str, Any]] = []
        first: I2CError | None = None
        for port, driver in sorted(self.sensors.items()):
            entry: dict[str, Any] = {"port": port, "sensor": None, "ok": True}
            if driver is not None:
                entry["sensor"] = driver.model
                seq = self.sequencers[port]
                try:
                    with seq.lock:
                        driver.read_chip_id()
                except I2CError as e:
                    entry.update(ok=False, error="i2c", detail=str(e))
                    first = first or e
                entry["frame"] = seq.this_frame
            ports.append(entry)
        streams_ok = all(self._stream_health(entry) for entry in ports)
        return {
            "status": "ok" if first is None and streams_ok else "degraded",
            "board": self.board.name,
            "uptime_s": round((time.time_ns() - self.started_ns) / 1e9, 3),
            "ports": ports,
            **({} if first is None else {"error": "i2c", "detail": str(first)}),
        }

    def _stream_health(self, entry: dict[str, Any]) -> bool:
        """Add the port's stream (v4l2, lepton boards) to its entry; False if not streaming."""
        status = getattr(self.board, "port_status", None)
        if status is None:
            return True
        stream = status(entry["port"])
        entry["stream"] = stream
        if stream["state"] == "streaming":
            return True
        entry.update(ok=False, error=stream["state"], detail=stream.get("detail", ""))
        return False

    def close(self) -> None:
        """Close the event streams, the board, then the store (pending writes flushed)."""
        self.events.close()
        self.board.close()
        self.capture_pool.close()
        if self.store is not None:
            self.store.close()
