"""A stock NC393's firmware on the simulated board: what parsedit.php and imgsrv reach.

Elphel's own driver stack is, like elphel-camd, Elphel's frame-parameter model on the
same chips, so the sensor side here is the daemon's `CameraService` run in process on
the `SimCameraBoard`; what differs is the surface. `StockFirmware` adds what the daemon
lacks (each port's compressor, `elphel_sim.stock.compressor`) and behaves as the stock
camera does where the daemon would refuse:

- a write the sensor cannot take (a value out of range, a read-only or unsupported name)
  is dropped, parameter by parameter, and nothing says so: the stock camera returns no
  errors for values, a client reads back to see what took effect;
- a write whose frame is too close for the sensor's latency (``*0``, ``*1``) takes effect
  at the earliest frame it can reach;
- a port without a sensor reads 0 for every parameter and ignores writes.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator, Mapping
from typing import Any

from elphel_camd.errors import CameraError, FrameTooLateError
from elphel_camd.params import PARAMS, TRIG_SNAPSHOT, TRIGSEQ
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.stock import compressor
from elphel_sim.stock.compressor import CompressorSchedule, EncodedFrame, encode_frame
from elphel_sim.stock.parsedit import MAX_AHEAD, MIN_AHEAD, ParseditQuery, Write

PORTS = 4  # the NC393 has four sensor ports, whatever the scenario connects
# Stock parameters the simulated firmware answers with fixed values (not modelled further).
FIXED = {"SENSOR_RUN": 2, "COMPRESSOR_RUN": 2, "TRIG_CONDITION": 0, "BAYER": 0}
FIXED |= dict.fromkeys(("DCM_HOR", "DCM_VERT", "BIN_HOR", "BIN_VERT"), 1)
KNOWN = frozenset(PARAMS) | compressor.NAMES | frozenset(FIXED)
WAIT_TIMEOUT_S = 30.0
ENCODED_KEPT = 8  # encoded frames kept per port: clients ask for the same frame repeatedly


class StockFirmware:
    """The simulated board as a stock NC393 firmware presents it.

    Parameters
    ----------
    board
        The simulated board, its frame clock running (`SimCameraBoard.start_clock`).
    service
        The daemon's service on that board (made here if None).
    """

    def __init__(self, board: SimCameraBoard, service: CameraService | None = None) -> None:
        self.board = board
        self.service = service if service is not None else CameraService(board)
        self.compressors = {
            port: CompressorSchedule(raw_only=driver.bayer is None)
            for port, driver in self.service.sensors.items()
            if driver is not None
        }
        self._request_lock = threading.Lock()
        self._frames = threading.Condition()
        self._newest = {port: 0 for port in self.compressors}
        self.read_pointers: dict[int, int] = {}  # imgsrv "save", shared by its clients
        self._encoded: dict[tuple[int, int], tuple[EncodedFrame, dict[str, Any]]] = {}
        self._encoding: dict[tuple[int, int], threading.Lock] = {}  # one encoder per frame
        self._encoded_lock = threading.Lock()
        board.on_frame_sync(self._frame_sync)

    def _frame_sync(self, port: int, frame: int, timestamp_ns: int) -> None:
        with self._frames:
            self._newest[port] = frame
            self._frames.notify_all()

    # -- frames ----------------------------------------------------------------------------

    def has_sensor(self, port: int) -> bool:
        return port in self.compressors

    def frame(self, port: int) -> int:
        """The port's current (newest) frame number; 0 on a port without a sensor."""
        if not self.has_sensor(port):
            return 0
        return self.service.sequencers[port].this_frame

    def wait_frame(self, port: int, frame: int, *, timeout_s: float = WAIT_TIMEOUT_S) -> bool:
        """Wait until the port's frame ``frame`` has started; False on timeout."""
        if not self.has_sensor(port):
            return False
        deadline = time.monotonic() + timeout_s
        with self._frames:
            while self._newest[port] < frame:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._frames.wait(min(remaining, 0.5))
        return True

    def oldest(self, port: int) -> int:
        """The oldest frame still in the port's ring buffer (0 if none)."""
        if not self.has_sensor(port):
            return 0
        ring = self.board.fpga[port].ring
        newest = self.frame(port)
        return max(1, newest - len(ring) + 1) if newest else 0

    def encoded(self, port: int, frame: int) -> tuple[EncodedFrame, dict[str, Any]]:
        """Frame ``frame`` of a port as imgsrv serves it, and the daemon's metadata of it.

        A frame taken does not change: it is formed and encoded once, however many
        requests ask for it at once, and kept for the next request of it (the newest
        `ENCODED_KEPT` frames of each port, none once the board is closed).
        """
        key = (port, frame)
        with self._encoded_lock:
            kept = self._encoded.get(key)
            if kept is not None:
                return kept
            lock = self._encoding.setdefault(key, threading.Lock())
        try:
            with lock:
                return self._encode_once(port, frame)
        finally:
            with self._encoded_lock:
                self._encoding.pop(key, None)

    def _encode_once(self, port: int, frame: int) -> tuple[EncodedFrame, dict[str, Any]]:
        with self._encoded_lock:
            kept = self._encoded.get((port, frame))
        if kept is not None:
            return kept  # encoded by the request this one waited for
        got, metadata = self.service.capture(port, frame=frame)
        state = self.compressors[port].state_at(got.frame)
        bits = self.service.sensor(port).bits
        result = encode_frame(got.image, metadata, state, bits=bits), metadata
        with self._encoded_lock:
            if self.board.closed:
                self._encoded.clear()
                return result
            self._encoded[(port, got.frame)] = result
            mine = sorted(f for p, f in self._encoded if p == port)
            for old in mine[:-ENCODED_KEPT]:
                del self._encoded[(port, old)]
        return result

    def kept(self, port: int, frame: int) -> tuple[EncodedFrame, dict[str, Any]] | None:
        """The frame as `encoded` gave it before, if it is still kept; None otherwise."""
        with self._encoded_lock:
            return self._encoded.get((port, frame))

    def head(self, port: int, frame: int) -> tuple[EncodedFrame, dict[str, Any]] | None:
        """The first bytes of the frame's JP4/JP46 file and its metadata, with no image formed.

        The start marker and the Exif segment (`compressor.frame_head`), from the frame's
        record (its time) and the parameters in effect for it; `encoded`'s file starts
        with them. None for a raw frame (COLOR 15), sent whole.

        Raises
        ------
        FrameNotAvailableError
            The frame is not taken yet or no longer kept.
        """
        record = self.board.frame_record(port, frame)
        params = self.service.params(port, frame=frame)
        state = self.compressors[port].state_at(frame)
        metadata = {"frame": frame, "timestamp_ns": record.timestamp_ns, "port": port, **params}
        shape = (params["WOI_HEIGHT"], params["WOI_WIDTH"])
        head = compressor.frame_head(metadata, state, shape=shape)
        return None if head is None else (head, metadata)

    def hold(self, port: int, frame: int) -> None:
        """Keep a frame of the ring available until `release`, even once it leaves the ring.

        Raises
        ------
        FrameNotAvailableError
            The frame is no longer in the ring buffer.
        """
        self.board.pin_frames(port, 1, frame=frame)

    def release(self, port: int, frame: int) -> None:
        """Let go of a frame `hold` kept (held by others, it stays)."""
        self.board.release_frames(port, [frame])

    def close(self) -> None:
        """Let go of the encoded frames and close the service (and with it the board)."""
        with self._encoded_lock:
            self._encoded.clear()
        self.service.close()

    def trigger(self, port: int) -> bool:
        """One internal trigger (imgsrv's ``trig``); False if the port is not in snapshot mode.

        The common trigger generator fires once now; ports in snapshot mode (TRIG 4,
        TRIG_CONDITION 0) take one frame each; free-running ports are not affected.
        """
        if not self.has_sensor(port):
            return False
        state = self.service.params(port)
        if not state["TRIG"] & TRIG_SNAPSHOT:
            return False
        master = state["TRIG_MASTER"]
        if not self.has_sensor(master):
            return False
        m = self.service.params(master)
        base = {"FRAME": 0, "TRIG_MASTER": master, "TRIG_DELAY": m["TRIG_DELAY"]}
        base["TRIG_DECIMATE"] = m["TRIG_DECIMATE"]
        # Stop, then one trigger at this moment (the generator re-arms on a new period).
        self.board.program(master, TRIGSEQ, {**base, "TRIG_PERIOD": 0})
        self.board.program(master, TRIGSEQ, {**base, "TRIG_PERIOD": 1})
        return True

    # -- parameters ------------------------------------------------------------------------

    def read(self, port: int, names: tuple[str, ...]) -> dict[str, int]:
        """The values in effect now of named parameters (0 for all on an empty port)."""
        if not self.has_sensor(port):
            return dict.fromkeys(names, 0)
        params = self.service.params(port)
        comp = self.compressors[port].state_at(params["FRAME"])
        params.update(comp)
        params["BITS"] = 16 if comp["COLOR"] == compressor.RAW else 8
        return {name: int(params.get(name, FIXED.get(name, 0))) for name in names}

    def parsedit(self, query: ParseditQuery) -> dict[str, int]:
        """Apply an immediate parsedit request; return the named values from before it.

        Writes are grouped by ``*ahead`` and issued in that order, each group for frame
        F + ahead, F being the frame when the request came (the ``FRAME`` of the
        answer). A group more than 6 frames ahead is issued once the target is 4 frames
        ahead (the script waits for that frame), so the answer comes after that wait.
        """
        port = query.sensor_port
        todo: dict[int, dict[int, dict[str, int]]] = {}
        for w in query.writes:
            for p in self._ports_of(w, port):
                todo.setdefault(w.ahead, {}).setdefault(p, {})[w.name] = w.value
        with self._request_lock, contextlib.ExitStack() as held:
            if self.has_sensor(port):
                held.enter_context(self.service.sequencers[port].lock)
            before = self.read(port, query.names)
            zero = {p: self.frame(p) for p in self.compressors}
            since = 0
            for ahead in sorted(todo):
                if ahead - MAX_AHEAD > since:
                    held.close()  # the frame clock must run while the script waits
                    since = ahead - MIN_AHEAD
                    self.wait_frame(port, zero.get(port, 0) + since)
                for p, changes in todo[ahead].items():
                    self._write(p, changes, frame=zero[p] + ahead)
        return before

    def _ports_of(self, write: Write, port: int) -> Iterator[int]:
        ports = [port] if write.mask is None else [p for p in range(PORTS) if write.mask >> p & 1]
        return (p for p in ports if self.has_sensor(p))

    def _write(self, port: int, changes: Mapping[str, int], *, frame: int) -> None:
        comp = {k: v for k, v in changes.items() if k in compressor.NAMES}
        sensor = {k: v for k, v in changes.items() if k in PARAMS}
        if comp:
            self.compressors[port].set(max(frame, self.frame(port) + 1), comp)
        if not sensor:
            return
        try:
            self._set(port, sensor, frame)
        except (CameraError, ValueError):
            for name, value in sensor.items():  # no all-or-nothing: each one that fits
                with contextlib.suppress(CameraError, ValueError):
                    self._set(port, {name: value}, frame)

    def _set(self, port: int, changes: dict[str, Any], frame: int) -> None:
        try:
            self.service.set_params(port, changes, frame=frame)
        except FrameTooLateError:
            self.service.set_params(port, changes)  # the earliest frame it can reach
