"""The camera service: the daemon's view of a board, what the REST API calls.

`CameraService` detects the sensor on every port of a `Board`, runs a frame sequencer per
port, keeps the common trigger settings in sync across ports, restores and saves the
accepted parameters (`ParamStore`), captures frames with their metadata, gives raw register
access and reports health. A PATCH of parameters enters here (`CameraService.set_params`)
and leaves through the port's `PortSequencer`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Generator, Mapping
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Any, TypeVar

from elphel_camd import __version__
from elphel_camd.boards.base import Board, Frame
from elphel_camd.errors import (
    CameraError,
    FrameNotAvailableError,
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
from elphel_camd.frame_metadata import frame_metadata
from elphel_camd.params import COMMON_TRIGGER_PARAMS, PARAMS
from elphel_camd.sensors import SensorDriver, detect, register_file
from elphel_camd.sensors.registers import Access, Register
from elphel_camd.sequencer import MAX_AHEAD, PortSequencer
from elphel_camd.store import ParamStore

log = logging.getLogger(__name__)

T = TypeVar("T")


class CaptureBusyError(CameraError):
    """Too many captures are waiting for frames already (the capture wait pool is full)."""


class CapturePool:
    """The threads that wait for frames, apart from the pool that serves other requests.

    A capture can wait a long time (a stopped trigger waits for its timeout); here such
    waits take at most ``workers`` threads, and requests beyond ``max_waiting`` are refused
    with `CaptureBusyError` instead of queueing without end, so parameter reads and writes
    never wait for captures.

    Parameters
    ----------
    workers
        Threads that wait for frames (and form their images) at the same time.
    max_waiting
        Captures running or queued at most; one more is refused.
    """

    def __init__(self, workers: int = 16, max_waiting: int = 64) -> None:
        self.workers = workers
        self.max_waiting = max_waiting
        self.waiting = 0
        self._executor = ThreadPoolExecutor(workers, thread_name_prefix="camd-capture")

    async def run(self, fn: Callable[[], T]) -> T:
        """``fn()`` in a capture thread (CaptureBusyError if ``max_waiting`` are in)."""
        if self.waiting >= self.max_waiting:
            raise CaptureBusyError(
                f"capture wait pool full: {self.waiting} captures are waiting for frames "
                f"(limit {self.max_waiting}); retry later"
            )
        self.waiting += 1  # only the event loop's thread counts
        try:
            return await asyncio.get_running_loop().run_in_executor(self._executor, fn)
        finally:
            self.waiting -= 1

    def close(self) -> None:
        self._executor.shutdown(wait=False, cancel_futures=True)


# Parameters that need a part of the board beyond the sensor (a board capability).
_NEEDS = {
    "TRIG_PERIOD": "trigger",
    "TRIG_DELAY": "trigger",
    "TRIG_DECIMATE": "trigger",
    "PF_HEIGHT": "photofinish",
}


class CameraService:
    """The daemon's view of a board: sensors, their sequencers, capture with metadata.

    Formerly ``elphel_camd.board.Camera``.

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
        # Parameters of the frames a burst holds, taken when each frame starts: a held
        # frame can be sent after the sequencer's history has forgotten it.
        self._held_params: dict[int, dict[int, dict[str, int] | None]] = {
            port: {} for port in self.sequencers
        }
        self._held_counts: dict[int, Counter[int]] = {port: Counter() for port in self.sequencers}
        self._held_lock = threading.Lock()
        board.on_frame_sync(self._frame_sync)

    def _frame_sync(self, port: int, frame: int, timestamp_ns: int) -> None:
        seq = self.sequencers.get(port)
        if seq is None:
            return
        seq.on_frame_sync(frame, timestamp_ns)
        held = self._held_params[port]
        if frame in held:
            params = self.params(port, frame=frame)
            with self._held_lock:
                if frame in held:
                    held[frame] = params
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
        copied to the other ports, as Elphel's drivers do.
        """
        seq = self.sequencer(port)
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
        common = {k: v for k, v in changes.items() if k in COMMON_TRIGGER_PARAMS}
        # One lock per port; a change of the common trigger holds every port (in order).
        ports = sorted(self.sequencers) if common else [port]
        with contextlib.ExitStack() as held:
            for p in ports:
                held.enter_context(self.sequencers[p].lock)
            if common:
                master = changes.get("TRIG_MASTER", seq.state_at(seq.this_frame)["TRIG_MASTER"])
                if master != port:
                    raise ParameterRangeError(
                        "TRIG_PERIOD", common["TRIG_PERIOD"], f"set on the master port {master}"
                    )
                others = [s for p, s in self.sequencers.items() if p != port]
                for other in others:  # check first: all ports or none
                    other.check(common)
            # All or nothing, saving included: a change that cannot be saved (disk full,
            # read-only state directory) is taken back and refused.
            before = {p: self.sequencers[p].schedule() for p in ports}
            try:
                target = seq.request(changes, frame=frame, ahead=ahead)
                if common:
                    for other in others:
                        other.request(common)
                if not self.scheduled:
                    seq.flush()
                for p in ports:
                    self._versions[p] += 1
                    self._save(p, self._versions[p], self._persistent(p))
            except (StateWriteError, I2CError) as e:
                # All or nothing: take the change back; a board programmed at once (no
                # frame syncs) gets the previous state written again.
                for p in ports:
                    self.sequencers[p].restore_schedule(before[p])
                if not self.scheduled:
                    try:
                        seq.flush()
                    except I2CError as again:
                        log.error("port %d: previous state not written back: %s", port, again)
                if isinstance(e, I2CError):
                    raise PortI2CError(port, e) from e
                raise
        self.events.publish("params", {"port": port, "frame": target, "changes": dict(changes)})
        return target

    # -- frames ----------------------------------------------------------------------------

    def capture(self, port: int, *, frame: int | None = None) -> tuple[Frame, dict[str, Any]]:
        """The next frame of a port (or a recent one) and its metadata."""
        driver = self.sensor(port)
        self._check_frame(port, frame)
        got = self.board.capture(port, frame=frame)
        with self._held_lock:
            params = self._held_params[port].get(got.frame)
        if params is None:
            params = self.params(port, frame=got.frame)
        metadata = frame_metadata(
            got, port=port, sensor=driver.model, bayer=driver.bayer, params=params
        )
        return got, metadata

    def _check_frame(self, port: int, frame: int | None) -> None:
        if frame is None:
            return
        newest = self.sequencers[port].this_frame
        if frame > newest + MAX_AHEAD:
            raise FrameNotAvailableError(
                f"port {port}: frame {frame} is not taken yet (current frame {newest}; "
                f"capture waits for at most {MAX_AHEAD} frames ahead)"
            )

    def burst(
        self, port: int, count: int, *, frame: int | None = None
    ) -> Generator[tuple[Frame, dict[str, Any]], None, None]:
        """``count`` consecutive frames of a port, from the next one (or from ``frame``).

        On a board that can hold frames (``pin_frames``) every frame of the burst is held
        from the start until the consumer has taken it, so a consumer slower than the
        frame rate (a full-resolution burst over the network) still gets all of them.
        Elsewhere a frame overwritten in the ring before it was fetched raises
        `FrameNotAvailableError`. Either way the burst yields every frame or raises.
        """
        if count < 1:
            raise ParameterRangeError("count", count, "1 or more")
        pin = getattr(self.board, "pin_frames", None)
        release = getattr(self.board, "release_frames", None)
        if pin is None or release is None:
            first = self.capture(port, frame=frame)
            yield first
            for k in range(1, count):
                yield self.capture(port, frame=first[0].frame + k)
            return
        self.sensor(port)
        self._check_frame(port, frame)
        start = self._hold_params(port, count, frame)
        done = start  # frames before this one are released
        try:
            pin(port, count, frame=start)
        except BaseException:
            self._release_params(port, range(start, start + count))
            raise
        try:
            for k in range(count):
                got = self.capture(port, frame=start + k)
                yield got
                release(port, [start + k])
                self._release_params(port, [start + k])
                done = start + k + 1
        finally:
            release(port, range(done, start + count))
            self._release_params(port, range(done, start + count))

    def _hold_params(self, port: int, count: int, frame: int | None) -> int:
        """Keep the parameters of ``count`` frames from ``frame`` (or the next one)."""
        seq = self.sequencers[port]
        held = self._held_params[port]
        counts = self._held_counts[port]
        with seq.lock, self._held_lock:  # no frame starts in between
            start = seq.this_frame + 1 if frame is None else frame
            for n in range(start, start + count):
                held.setdefault(n, None)
                counts[n] += 1
        for n in range(start, min(start + count, seq.this_frame + 1)):
            with contextlib.suppress(FrameNotAvailableError):
                params = self.params(port, frame=n)
                with self._held_lock:
                    held[n] = params
        return start

    def _release_params(self, port: int, frames: range | list[int]) -> None:
        held = self._held_params[port]
        counts = self._held_counts[port]
        with self._held_lock:
            for n in frames:
                if counts[n] > 1:
                    counts[n] -= 1
                else:
                    counts.pop(n, None)
                    held.pop(n, None)

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
        return {
            "status": "ok" if first is None else "degraded",
            "board": self.board.name,
            "uptime_s": round((time.time_ns() - self.started_ns) / 1e9, 3),
            "ports": ports,
            **({} if first is None else {"error": "i2c", "detail": str(first)}),
        }

    def close(self) -> None:
        """Close the event streams, the board, then the store (pending writes flushed)."""
        self.events.close()
        self.board.close()
        self.capture_pool.close()
        if self.store is not None:
            self.store.close()
