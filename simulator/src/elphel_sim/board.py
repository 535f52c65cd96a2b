"""The simulated camera board: I2C buses with chips, FPGA timing and trigger, image path.

It implements the daemon's `Board` protocol, so the real daemon runs on it unchanged; the
daemon finds it as ``--board sim`` through the ``elphel_camd.boards`` entry point.

Time is virtual. Tests step it (`sim_advance`, or a capture that waits for the next frame
advances it); `start_clock` runs it against the wall clock for a served rig.
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Mapping

import numpy as np

from elphel_camd.boards import Frame
from elphel_camd.errors import CaptureUnavailableError, FrameNotAvailableError, PortError
from elphel_camd.i2c.bus import I2CBus
from elphel_sim.calib_board import pose_json
from elphel_sim.chips.bus import SimI2CBus
from elphel_sim.chips.imx219 import SimIMX219
from elphel_sim.chips.lepton35 import SimLepton35
from elphel_sim.chips.mt9f002 import SimMT9F002
from elphel_sim.chips.mt9p006 import SimMT9P006
from elphel_sim.chips.sensor import SimSensor
from elphel_sim.forming import FormingPool
from elphel_sim.fpga import Camsync, FrameRecord, PortFPGA
from elphel_sim.frame_clock import FrameClock
from elphel_sim.scenarios import PortSpec, Scenario, build

FrameSync = Callable[[int, int, int], None]
TRUTH_FRAMES = 100_000  # frames whose true pose is kept per port (sim_frame_truth)
# A frame whose image was asked for stays available this long after, out of the ring too:
# a capture that its client gave up on while the image formed (a busy machine) and asked
# for again gets the same frame, formed once.
FORMED_KEEP_S = 45.0
# ... and only the latest of them: a retried quad set needs four, while a long burst asked for
# at full resolution must not hold gigabytes for those 45 s.
FORMED_KEEP_FRAMES = 16

# Simulated chips by model name (PortSpec.model).
SIM_SENSORS: dict[str, Callable[[], SimSensor]] = {
    "MT9P006": SimMT9P006,
    "MT9F002": SimMT9F002,
    "LEPTON35": SimLepton35,
    "IMX219": SimIMX219,
}


class SimCameraBoard:
    """A simulated camera board serving a scenario's world.

    Parameters
    ----------
    scenario
        The world and the ports.
    seed
        Seed of the sensor noise (each frame of each port draws from its own stream).
    noise
        False renders the noise-free expectation (exact tests).
    forming
        Where images are formed: ``"thread"`` in the capturing thread, or ``"process"`` in
        a child process (`elphel_sim.forming`), leaving this process's CPU to the daemon.
    """

    name = "sim"
    capabilities = frozenset({"frames", "capture", "trigger", "photofinish"})

    def __init__(
        self, scenario: Scenario, *, seed: int = 0, noise: bool = True, forming: str = "thread"
    ) -> None:
        if forming not in ("thread", "process"):
            raise ValueError(f"forming={forming!r}; allowed: thread, process")
        self.world = scenario.world
        self.seed = seed
        self.noise = noise
        self.ports: dict[int, PortSpec] = dict(enumerate(scenario.ports))
        self.quad = scenario.quad
        self.calib = scenario.calib
        self.daemon_per_port = scenario.daemon_per_port
        self._buses: dict[int, SimI2CBus] = {}
        self.chips: dict[int, SimSensor] = {}
        self.fpga: dict[int, PortFPGA] = {}
        self.camsync = Camsync()
        self.now_s = 0.0
        self._subscribers: list[FrameSync] = []
        self._timestamp_skew_ns: dict[int, int] = {}
        self._truth: dict[int, OrderedDict[int, dict[str, object]]] = {}
        self._cond = threading.Condition(threading.RLock())
        self._clock: FrameClock | None = None
        self._closed = False
        self._clock_on_subscribe = False  # start_clock at the first on_frame_sync
        self._forming = threading.Lock()
        self._former = FormingPool() if forming == "process" else None
        # Frames a multi-frame capture holds until sent: port -> frame -> record (None
        # until the frame is taken). They stay here after leaving the ring buffer.
        self._pins: dict[int, dict[int, FrameRecord | None]] = {}
        self._pin_counts: dict[int, Counter[int]] = {}  # captures holding each frame
        # Frames whose image was asked for: (port, frame) -> (record, when, its forming lock).
        self._formed: OrderedDict[tuple[int, int], tuple[FrameRecord, float, threading.Lock]]
        self._formed = OrderedDict()
        for port, spec in self.ports.items():
            bus = SimI2CBus(f"port {port}")
            if spec.model in SIM_SENSORS:
                chip = SIM_SENSORS[spec.model]()
                bus.attach(chip.address, chip)
                self.chips[port] = chip
                self.fpga[port] = PortFPGA()
                self._truth[port] = OrderedDict()
            elif spec.model is not None:
                allowed = ", ".join([*SIM_SENSORS, "None"])
                raise ValueError(
                    f"port {port}: simulated sensor {spec.model!r}; allowed: {allowed}"
                )
            self._buses[port] = bus
        for port in self.fpga:
            self._schedule_next(port)

    # -- the Board protocol ----------------------------------------------------------------

    def buses(self) -> Mapping[int, I2CBus]:
        return self._buses

    def bus(self, port: int) -> SimI2CBus:
        return self._buses[port]

    def on_frame_sync(self, callback: FrameSync) -> None:
        """Call ``callback(port, frame, timestamp_ns)`` at every frame start."""
        self._subscribers.append(callback)
        if self._clock_on_subscribe:
            self._clock_on_subscribe = False
            self.start_clock()

    def program(self, port: int, function: str, state: Mapping[str, int]) -> None:
        """FPGA-side settings of a function, taking effect at the state's target frame."""
        fpga = self.fpga.get(port)
        if fpga is None:
            return
        with self._cond:
            fpga.program(port, function, state)
            if state.get("FRAME", 0) <= fpga.frame:
                self._apply_pending(port)
                self._schedule_next(port)

    def capture(self, port: int, *, frame: int | None = None, timeout_s: float = 10.0) -> Frame:
        """The next frame of a port, or frame ``frame`` from the ring buffer."""
        if port not in self.ports:
            raise PortError(f"port {port} does not exist; ports: {sorted(self.ports)}")
        fpga = self.fpga.get(port)
        if fpga is None:
            raise CaptureUnavailableError(f"port {port}: no sensor on this simulated port")
        wanted = fpga.frame + 1 if frame is None else frame
        record = self._wait_for(port, wanted, timeout_s)
        return Frame(
            image=self._image(record),
            frame=record.frame,
            timestamp_ns=record.timestamp_ns,
            strip_period_ns=round(record.strip_period_s * 1e9) if record.strips else 0,
        )

    def frame_record(self, port: int, frame: int) -> FrameRecord:
        """What the board recorded of a frame taken and still kept, without forming its image.

        Raises
        ------
        FrameNotAvailableError
            The frame is not taken yet, or no longer kept (out of the ring buffer, not held).
        """
        fpga = self.fpga.get(port)
        if fpga is None:
            raise CaptureUnavailableError(f"port {port}: no sensor on this simulated port")
        if frame > fpga.frame:
            raise FrameNotAvailableError(
                f"port {port}: frame {frame} is not taken yet (newest {fpga.frame})"
            )
        return self._wait_for(port, frame, 0.0)

    def pin_frames(self, port: int, count: int, *, frame: int | None = None) -> int:
        """Hold ``count`` consecutive frames (from the next one or ``frame``) until released.

        A held frame stays available to `capture` after it leaves the 64-frame ring, so a
        multi-frame capture slower than the frame rate still gets every frame. Returns the
        first frame's number; release each frame with `release_frames`.
        """
        if port not in self.ports:
            raise PortError(f"port {port} does not exist; ports: {sorted(self.ports)}")
        fpga = self.fpga.get(port)
        if fpga is None:
            raise CaptureUnavailableError(f"port {port}: no sensor on this simulated port")
        with self._cond:
            if self._closed:
                raise CaptureUnavailableError(f"port {port}: the board is closed")
            first = fpga.frame + 1 if frame is None else frame
            ring = {r.frame: r for r in fpga.ring}
            if first <= fpga.frame and first not in ring:
                raise FrameNotAvailableError(
                    f"port {port}: frame {first} is no longer in the ring buffer "
                    f"(frames {fpga.ring[0].frame}..{fpga.frame})"
                )
            pins = self._pins.setdefault(port, {})
            counts = self._pin_counts.setdefault(port, Counter())
            for n in range(first, first + count):
                if n not in pins:
                    pins[n] = ring.get(n)
                counts[n] += 1
        return first

    def release_frames(self, port: int, frames: range | list[int]) -> None:
        """Let go of frames this caller held (a frame held by others stays held)."""
        with self._cond:
            pins = self._pins.get(port, {})
            counts = self._pin_counts.get(port, Counter())
            for n in frames:
                if counts[n] > 1:
                    counts[n] -= 1
                else:
                    counts.pop(n, None)
                    pins.pop(n, None)

    def close(self) -> None:
        """Stop the clock and let go of the frames and the frame-sync subscribers.

        Captures still waiting for a frame fail at once, later ones too. The subscribers
        (the daemon's service, which holds this board) and the frame images go, so a
        closed board and its service are freed as soon as their last user lets go.
        """
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self.stop_clock()
        if self._former is not None:
            self._former.close()
        with self._cond:
            self._subscribers.clear()
            for fpga in self.fpga.values():
                fpga.ring.clear()
            self._pins.clear()
            self._pin_counts.clear()
            self._formed.clear()

    @property
    def closed(self) -> bool:
        """Whether `close` was called."""
        return self._closed

    # -- time ------------------------------------------------------------------------------

    def _apply_pending(self, port: int) -> None:
        periods = self.fpga[port].apply_due()
        for period_10ns in periods:
            self.camsync.program(period_10ns, self.now_s)
        if periods:
            for other in self.fpga:
                if other != port:
                    self._schedule_next(other)

    def _schedule_next(self, port: int) -> None:
        """When the port's next frame starts, from its sensor and FPGA state in effect."""
        fpga, chip = self.fpga[port], self.chips[port]
        fpga.schedule_next(
            chip.timing(),
            sensor_snapshot=chip.is_snapshot(),
            camsync=self.camsync,
            now_s=self.now_s,
        )

    def _start_frame(self, port: int) -> tuple[int, int]:
        fpga, chip = self.fpga[port], self.chips[port]
        self.now_s = fpga.start_frame()
        self.world.time_s = self.now_s
        with self._buses[port].lock:
            chip.latch(fpga.frame)
        self._apply_pending(port)
        strip_period_s = fpga.strip_period_s(
            chip.timing(), sensor_snapshot=chip.is_snapshot(), camsync=self.camsync
        )
        strips = fpga.settings.pf_strips
        timestamp_ns = round(fpga.next_timestamp_s * 1e9) + self._timestamp_skew_ns.get(port, 0)
        spec = self.ports[port]
        fpga.ring.append(
            FrameRecord(
                port=port,
                frame=fpga.frame,
                start_s=self.now_s,
                timestamp_ns=timestamp_ns,
                registers=chip.image_registers(),
                pose=self.world.camera_pose(spec.mount),
                carriage_mm=self.world.rig.carriage_mm,
                strips=strips,
                strip_period_s=strip_period_s,
                board=self.world.board,
            )
        )
        record = fpga.ring[-1]
        self._forget_formed(time.monotonic() - FORMED_KEEP_S)
        pins = self._pins.get(port)
        if pins is not None and record.frame in pins:
            pins[record.frame] = record
        truth = self._truth[port]
        truth[record.frame] = {
            "port": port,
            "frame": record.frame,
            "start_s": record.start_s,
            "timestamp_ns": record.timestamp_ns,
            "carriage_mm": record.carriage_mm,
            "camera_position_mm": record.pose.position_mm.tolist(),
            "strips": record.strips,
        }
        if record.board is not None:
            truth[record.frame]["board"] = pose_json(record.board)
        if len(truth) > TRUTH_FRAMES:
            truth.popitem(last=False)
        self._schedule_next(port)
        return fpga.frame, timestamp_ns

    def sim_step(self) -> tuple[int, int, int]:
        """Start the next frame on whichever port is due first; return (port, frame, ts)."""
        with self._cond:
            if not self.fpga:
                raise CaptureUnavailableError("the simulated board has no sensor")
            port = min(self.fpga, key=lambda p: self.fpga[p].next_start_s)
            if math.isinf(self.fpga[port].next_start_s):
                raise CaptureUnavailableError(
                    "no port will start a frame: every port waits for a trigger that is stopped"
                )
            frame, ts = self._start_frame(port)
        for callback in self._subscribers:
            callback(port, frame, ts)
        with self._cond:
            self._cond.notify_all()
        return port, frame, ts

    def sim_advance(self, *, frames: int = 1, port: int | None = None) -> None:
        """Run until ``frames`` more frames started (on ``port``, or on any port)."""
        done = 0
        while done < frames:
            p, _, _ = self.sim_step()
            if port is None or p == port:
                done += 1

    def _wait_for(self, port: int, frame: int, timeout_s: float) -> FrameRecord:
        fpga = self.fpga[port]
        deadline = time.monotonic() + timeout_s
        while True:
            with self._cond:
                if self._closed:
                    raise CaptureUnavailableError(f"port {port}: the board is closing")
                held = self._pins.get(port, {}).get(frame)
                if held is None and (port, frame) in self._formed:
                    held = self._formed[(port, frame)][0]
                if held is not None:
                    return held
                for record in fpga.ring:
                    if record.frame == frame:
                        return record
                if frame <= fpga.frame:
                    raise FrameNotAvailableError(
                        f"port {port}: frame {frame} is no longer in the ring buffer "
                        f"(frames {fpga.ring[0].frame}..{fpga.frame})"
                    )
                if self._clock is not None:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        raise TimeoutError(
                            f"port {port}: frame {frame} did not come in {timeout_s} s"
                        )
                    self._cond.wait(min(remaining, 0.5))
                    continue
            self.sim_step()

    def sim_timestamp_skew(self, port: int, skew_ns: int = 0) -> None:
        """Fault: the port's frame timestamps run ``skew_ns`` off the common trigger's time.

        As a port whose timestamps do not come from the common sync would; 0 heals it.
        """
        if port not in self.fpga:
            raise PortError(f"port {port} has no simulated sensor; ports: {sorted(self.fpga)}")
        with self._cond:
            self._timestamp_skew_ns[port] = int(skew_ns)

    def sim_frame_truth(self, port: int, frame: int) -> dict[str, object]:
        """What the simulator knows of a past frame: its time and the camera's pose.

        Kept for the last `TRUTH_FRAMES` frames of each port, long after the images.
        """
        if port not in self.fpga:
            raise PortError(f"port {port} has no simulated sensor; ports: {sorted(self.fpga)}")
        with self._cond:
            truth = self._truth[port].get(frame)
        if truth is None:
            raise FrameNotAvailableError(f"port {port}: no record of frame {frame}")
        return dict(truth)

    def _image(self, record: FrameRecord) -> np.ndarray:
        # Rendered outside the board's lock: a full frame takes seconds, and the frame
        # clock and the other ports must not wait for it. The image depends only on the
        # record and the seed; two captures of one frame at once form it once.
        with self._cond:
            if record.image is not None:
                return record.image
            lock = self._keep_formed(record)
        with lock:
            with self._cond:
                if record.image is not None:
                    return record.image
                spec = self.ports[record.port]
                form_image = self.chips[record.port].form_image
            seed = [self.seed, record.port, record.frame] if self.noise else None
            if self._former is not None:  # child processes, side by side
                image = self._former.form(spec, record, self.world.scene, seed)
            # In this process one frame is formed at a time: forming is CPU-bound, and
            # several at once only take the interpreter from the clock and the requests.
            else:
                with self._forming:
                    rng = None if seed is None else np.random.default_rng(seed)
                    image = form_image(record, self.world, rng=rng, **spec.forming_options())
            with self._cond:
                if record.image is None:
                    record.image = image
                return record.image

    def _keep_formed(self, record: FrameRecord) -> threading.Lock:
        """Keep a frame asked for findable (`FORMED_KEEP_S`, `FORMED_KEEP_FRAMES`); its lock.

        Called with the board's lock held.
        """
        key = (record.port, record.frame)
        kept = self._formed.pop(key, None)
        lock = threading.Lock() if kept is None else kept[2]
        self._formed[key] = (record, time.monotonic(), lock)
        while len(self._formed) > FORMED_KEEP_FRAMES:
            self._formed.popitem(last=False)
        return lock

    def _forget_formed(self, before: float) -> None:
        """Let go of the frames asked for before ``before`` (monotonic seconds; lock held)."""
        while self._formed:
            key, (_, when, _) = next(iter(self._formed.items()))
            if when >= before:
                return
            del self._formed[key]

    # -- real time -------------------------------------------------------------------------

    def next_start_s(self) -> float:
        """Virtual time of the next frame start on any port (inf: none will start)."""
        with self._cond:
            return min((f.next_start_s for f in self.fpga.values()), default=math.inf)

    def start_clock(self, *, time_scale: float = 1.0) -> None:
        """Run virtual time against the wall clock in a thread (``time_scale`` x real time)."""
        if self._clock is None:
            self._clock = FrameClock(self, now_s=self.now_s, time_scale=time_scale)

    def stop_clock(self) -> None:
        if self._clock is not None:
            self._clock.stop()
            self._clock = None


def make_sim_board(
    *, scenario: str = "default", seed: int = 0, noise: bool = True
) -> SimCameraBoard:
    """Entry point for ``elphel-camd --board sim`` (options from ``--config``).

    The frame clock starts when the daemon subscribes to the frame syncs: a frame started
    before would be one whose parameters the daemon never recorded.
    """
    board = SimCameraBoard(build(scenario, seed=seed), seed=seed, noise=noise, forming="process")
    board._clock_on_subscribe = True
    return board
