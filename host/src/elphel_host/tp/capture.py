"""One trigger-synchronised set from a quad camera, written as a quad directory.

``elphel tp capture --camera URL --out QUAD_DIR`` then ``elphel tp QUAD_DIR --out DSI.tif``
take a quad camera from capture to DSI. The capture:

1. reads the daemon's info and requires a sensor on each of the four ports of the layout;
2. puts the four ports in snapshot mode on one common trigger, staged so the previous
   settings come back afterwards (:mod:`elphel_host.tp.trigger`);
3. waits until the change is in effect on every port, matches the ports' frame numbers
   by their timestamps (each frame of a trigger carries the trigger's time), picks a
   frame a few triggers ahead and waits until every port has taken it;
4. fetches that frame of every port from the daemon's ring buffer, checks that all four
   carry the same ``timestamp_ns``, the same size and the same Bayer pattern;
5. writes ``cam0..3.tif`` (the daemon's TIFFs, metadata included) and ``quad.json``
   (:class:`~elphel_host.tp.io.QuadManifest`) into a temporary directory next to the
   target and renames it into place, so a failure never leaves half a quad directory;
   with a calibration, a copy of its calibration.json goes in too, named in quad.json
   (checked first to be readable and for images of the set's size).

Which port is which camera, and where it sits, is the :mod:`~elphel_host.tp.layout`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from elphel_host.camera.client import CameraHTTPError, CapturedFrame
from elphel_host.camera.protocol import CameraInterface
from elphel_host.errors import (
    DeviceTimeout,
    FrameGoneError,
    QuadCaptureError,
    QuadCaptureTimeout,
)
from elphel_host.fileio import replacing_directory
from elphel_host.tp.calibrated import copy_calibration, read_calibration
from elphel_host.tp.io import QuadManifest, quad_cameras, write_quad_dir
from elphel_host.tp.layout import QuadLayout
from elphel_host.tp.trigger import (
    TICKS_PER_MS,
    TRIG_PERIOD_MIN_REPEAT,
    TRIG_SNAPSHOT,
    choose_trigger,
    on_common_trigger,
)

AHEAD_FRAMES = 2  # the set is taken this many triggers after every port is synchronised
# Without a period given, the set's frames, fetched one after another at the time one
# frame took, must be fetched within this many periods: half of a 64-frame ring buffer.
FIT_PERIODS = 32
DEFAULT_TIMEOUT_S = 60.0
# Without a timeout given, the frames are waited for at least this many trigger periods.
TIMEOUT_PERIODS = 16
SLOWER = 4  # a period too short: the error suggests this many times as long

# Metadata keys that are not frame parameters (kept per camera in quad.json anyway).
_FRAME_KEYS = ("frame", "timestamp_ns", "port", "sensor", "bayer")

#: ``progress(done, total, message)``: called after each step of a capture.
CaptureProgress = Callable[[int, int, str], None]


@dataclass(frozen=True)
class QuadCapture:
    """What `capture_quad` wrote: the directory, the frames taken and their common time.

    ``trigger_period_ms`` is the common trigger's period the set was taken at (given or
    chosen): a caller taking many sets passes it on, so that only the first is timed.
    """

    path: Path
    frames: dict[int, int]
    timestamp_ns: int
    width: int
    height: int
    bayer: str | None
    manifest: QuadManifest
    trigger_period_ms: float


def capture_quad(
    camera: CameraInterface,
    out: str | Path,
    *,
    layout: QuadLayout | None = None,
    trigger_period_ms: float | None = None,
    force: bool = False,
    timeout_s: float | None = None,
    progress: CaptureProgress | None = None,
    calibration: str | Path | None = None,
    say: Callable[[str], None] | None = None,
) -> QuadCapture:
    """Take one trigger-synchronised set from four sensor ports and write a quad directory.

    Parameters
    ----------
    camera
        Client of the camera daemon (with a token: capture and parameter changes write).
    out
        The quad directory to create. An existing empty directory is replaced; a
        non-empty one (or a file) only with ``force``.
    layout
        Ports and positions of cameras 0..3; default ports 0..3 on Elphel's square.
    trigger_period_ms
        Period of the common trigger. None: the master's repeating period, else
        `~elphel_host.tp.trigger.DEFAULT_TRIGGER_PERIOD_MS`, lengthened if one timed
        fetch says the set would not be fetched in `FIT_PERIODS` (said through ``say``).
    force
        Replace an existing non-empty ``out``.
    timeout_s
        Seconds to wait for the ports' frames; None: `DEFAULT_TIMEOUT_S` or
        `TIMEOUT_PERIODS` periods.
    progress
        Called as ``progress(done, total, message)`` after each step of the capture.
    calibration
        This quad's calibration.json or its directory: copied in and named in quad.json.
    say
        Called with one line saying the period chosen from the timed fetch.

    Raises
    ------
    QuadCaptureError
        Too few sensor ports, frames not of one trigger (different ``timestamp_ns``),
        images of different sizes or Bayer patterns, a camera that did not keep up
        (naming the options); `QuadCaptureTimeout` when the frames stop coming;
        `InputFormatError` for an unreadable or mis-sized ``calibration``.
    FileExistsError
        ``out`` exists, is not empty and ``force`` is not set.
    CameraClientError
        The daemon refused a setting or a request (its message names the value).
    """
    layout = QuadLayout() if layout is None else layout
    target = Path(out)
    _check_inputs(target, calibration, force=force)
    info = camera.info()
    sensors = _quad_sensors(camera, info, layout)
    before = _settings_before(camera, info, layout)
    master, period, wait_s = _trigger_and_wait(
        camera, before, layout.ports, (trigger_period_ms, timeout_s), say
    )
    step = progress or (lambda _done, _total, _message: None)
    given = (trigger_period_ms is not None, timeout_s is not None)
    captured = _take_set_in_time(camera, before, layout, (master, period), wait_s, step, given)
    timestamp_ns, (height, width), bayer = _check_set(captured, layout.ports)
    bits = max(int(sensors[p].get("bits", 16)) for p in layout.ports)
    manifest = _manifest(
        camera, info, layout, captured, master=master, period=period, bits=bits, bayer=bayer
    )
    manifest = _write_set(target, manifest, captured, layout, calibration, (width, height), force)
    step(4 + len(layout.ports), 4 + len(layout.ports), f"written {target}")
    return QuadCapture(
        path=target,
        frames={p: captured[p].frame for p in layout.ports},
        timestamp_ns=timestamp_ns,
        width=width,
        height=height,
        bayer=bayer,
        manifest=manifest,
        trigger_period_ms=period / TICKS_PER_MS,
    )


def _check_inputs(target: Path, calibration: str | Path | None, *, force: bool) -> None:
    """Refuse a target in the way or an unreadable calibration before the camera is touched."""
    check_target(target, force=force)
    if calibration is not None:
        read_calibration(calibration)


def _write_set(
    target: Path,
    manifest: QuadManifest,
    captured: Mapping[int, CapturedFrame],
    layout: QuadLayout,
    calibration: str | Path | None,
    image_size: tuple[int, int],
    force: bool,
) -> QuadManifest:
    """Write the quad directory (with a copy of the calibration); the manifest written."""
    with replacing_directory(target) as tmp:
        if calibration is not None:
            name = copy_calibration(calibration, tmp, image_size=image_size)
            manifest = replace(manifest, calibration=name)
        write_quad_dir(tmp, manifest, [captured[p].tiff for p in layout.ports])
        check_target(target, force=force)  # again: it may have appeared meanwhile
    return manifest


def _settings_before(
    camera: CameraInterface, info: Mapping[str, Any], layout: QuadLayout
) -> dict[int, dict[str, Any]]:
    """The ports' parameters before the capture, checked to allow a quad set."""
    if "trigger" not in info.get("capabilities", ["trigger"]):
        raise QuadCaptureError(
            f"{camera.url}: board {info.get('board')!r} has no common trigger; a quad set needs one"
        )
    before = {p: camera.params(p) for p in layout.ports}
    for p, params in before.items():
        if params.get("PF_HEIGHT", 0):
            raise QuadCaptureError(
                f"port {p} is in photo-finish mode (PF_HEIGHT={params['PF_HEIGHT']}); "
                "allowed for a quad set: PF_HEIGHT=0"
            )
    return before


def _trigger_and_wait(
    camera: CameraInterface,
    before: dict[int, dict[str, Any]],
    ports: tuple[int, ...],
    given: tuple[float | None, float | None],
    say: Callable[[str], None] | None,
) -> tuple[int, int, float]:
    """The master port, ``TRIG_PERIOD`` and seconds to wait for frames (`capture_quad`).

    ``given`` is the user's (period in ms, timeout in s), each None if not given.
    """
    period_ms, timeout_s = given
    master, period = choose_trigger(before, ports, period_ms)
    if period_ms is None:
        trig, repeat = before[ports[0]]["TRIG"], before[master]["TRIG_PERIOD"]
        # the next frame, unless the port waits for a trigger that does not repeat
        stopped = bool(trig & TRIG_SNAPSHOT) and repeat < TRIG_PERIOD_MIN_REPEAT
        period = _period_for_fetches(
            camera, ports, period, say or (lambda _line: None), newest=stopped
        )
    if timeout_s is None:
        timeout_s = max(DEFAULT_TIMEOUT_S, TIMEOUT_PERIODS * period / (1000 * TICKS_PER_MS))
    return master, period, timeout_s


def fetch_period(fetch_s: float, frames: int) -> int:
    """``TRIG_PERIOD`` (10 ns) at which ``frames`` fetches of ``fetch_s`` s take `FIT_PERIODS`.

    The fetches go one after another; the period is rounded up to whole milliseconds.
    """
    period_ms = math.ceil(frames * fetch_s * 1000 / FIT_PERIODS)
    return period_ms * TICKS_PER_MS


def _period_for_fetches(
    camera: CameraInterface,
    ports: tuple[int, ...],
    period: int,
    say: Callable[[str], None],
    *,
    newest: bool,
) -> int:
    """``period``, or longer if the set's frames would not be fetched in `FIT_PERIODS`.

    One frame of the first port is fetched and timed: the next one, or with ``newest``
    (frames do not come) the newest in its buffer. The choice is said in one line.
    """
    frame = camera.frame(ports[0])["frame"] if newest else None
    started = time.monotonic()
    camera.capture(ports[0], frame=frame)
    fetch_s = time.monotonic() - started
    needed = fetch_period(fetch_s, len(ports))
    chosen = max(period, needed)
    why = "longer than" if needed > period else "within"
    say(
        f"one frame took {fetch_s:.1f} s to fetch: {len(ports)} take {why} {FIT_PERIODS} "
        f"periods of {period / TICKS_PER_MS:g} ms; trigger period {chosen / TICKS_PER_MS:g} ms"
    )
    return chosen


def _take_set_in_time(
    camera: CameraInterface,
    before: dict[int, dict[str, Any]],
    layout: QuadLayout,
    trigger: tuple[int, int],
    timeout_s: float,
    step: CaptureProgress,
    given: tuple[bool, bool],
) -> dict[int, CapturedFrame]:
    """`_take_set`, its frames lost from the buffer or late (a busy host) said as such.

    ``given`` says whether the user gave the trigger period and the timeout: the error
    names the option to change, with a value for the period.
    """
    master, period = trigger
    started = time.monotonic()
    try:
        return _take_set(camera, before, layout, (master, period), started + timeout_s, step)
    except (FrameGoneError, DeviceTimeout) as e:
        period_given, timeout_given = given
        chosen = "given" if period_given else "chosen from one frame's fetch"
        hint = f"give a longer one (--trigger-period-ms {SLOWER * period / TICKS_PER_MS:g})"
        if isinstance(e, DeviceTimeout):
            hint += f" or a longer --timeout{f' than {timeout_s:g} s' if timeout_given else ''}"
        raise QuadCaptureError(
            f"{e}: fetching the set took {time.monotonic() - started:.1f} s at the {chosen} "
            f"{period / TICKS_PER_MS:g} ms trigger period; the camera did not keep up: {hint}"
        ) from e


def _take_set(
    camera: CameraInterface,
    before: dict[int, dict[str, Any]],
    layout: QuadLayout,
    trigger: tuple[int, int],
    deadline: float,
    step: CaptureProgress,
) -> dict[int, CapturedFrame]:
    """On the common trigger ``(master, period)``: wait for a set, fetch its frames."""
    master, period = trigger
    total = 4 + len(layout.ports)
    try:
        with on_common_trigger(camera, before, master=master, period=period) as applied:
            step(1, total, f"common trigger set ({period / TICKS_PER_MS:g} ms, master {master})")
            # one frame past the change, so every port's latest frame is a triggered one
            _wait_for(camera, {p: f + 1 for p, f in applied.items()}, deadline, period)
            step(2, total, "ports synchronised")
            frames = _pick_frames(camera, layout.ports, period)
            _wait_for(camera, frames, deadline, period)
            step(3, total, "set taken: " + ", ".join(f"port {p} #{f}" for p, f in frames.items()))

            def fetched(port: int, done: int) -> None:
                step(3 + done, total, f"port {port} frame {frames[port]} fetched")

            return _fetch(camera, frames, on_fetched=fetched)
    except CameraHTTPError as e:
        if e.parameter != "TRIG_PERIOD":
            raise
        raise QuadCaptureError(
            f"the camera refused a {period / TICKS_PER_MS:g} ms trigger period for these "
            f"settings ({e}); give a longer one (--trigger-period-ms)"
        ) from e


def check_target(target: Path, *, force: bool) -> None:
    """Refuse to replace an existing non-empty directory (or a file) unless ``force``.

    Raises
    ------
    FileExistsError
        ``target`` is a file or a non-empty directory and ``force`` is not set.
    """
    if force or not (target.exists() or target.is_symlink()):
        return
    if not target.is_dir():
        raise FileExistsError(f"{target} exists and is not a directory; give --force to replace it")
    if any(target.iterdir()):
        raise FileExistsError(f"{target} exists and is not empty; give --force to replace it")


def _quad_sensors(
    camera: CameraInterface, info: Mapping[str, Any], layout: QuadLayout
) -> dict[int, dict[str, Any]]:
    sensors: dict[int, dict[str, Any]] = {
        int(p["port"]): p["sensor"] for p in info.get("ports", []) if p.get("sensor")
    }
    have = sorted(sensors)
    missing = [p for p in layout.ports if p not in sensors]
    if missing:
        listed = ", ".join(map(str, have)) if have else "none"
        raise QuadCaptureError(
            f"a quad set needs a sensor on each of ports {', '.join(map(str, layout.ports))}; "
            f"{camera.url} has sensors on ports {listed} ({len(have)} of 4), "
            f"none on {', '.join(map(str, missing))}"
        )
    return {p: sensors[p] for p in layout.ports}


def _wait_for(
    camera: CameraInterface, frames: Mapping[int, int], deadline: float, period: int
) -> None:
    """Poll until each port's current frame is at least ``frames[port]``."""
    poll_s = min(0.05, period / 4e8)
    pending = dict(frames)
    last: dict[int, dict[str, int]] = {}
    while True:
        for p in list(pending):
            last[p] = camera.frame(p)
            if last[p]["frame"] >= pending[p]:
                del pending[p]
        if not pending:
            return
        if time.monotonic() > deadline:
            stuck = ", ".join(
                f"port {p} at frame {last[p]['frame']} (waiting for {f})"
                for p, f in pending.items()
            )
            raise QuadCaptureTimeout(
                f"frames did not come in time: {stuck}; is the common trigger running "
                f"(period {period / TICKS_PER_MS:g} ms), and is --timeout a few periods long?"
            )
        time.sleep(poll_s)


def _pick_frames(camera: CameraInterface, ports: tuple[int, ...], period: int) -> dict[int, int]:
    """Frame numbers of one future trigger on every port.

    Ports count frames on their own; in snapshot mode a frame's timestamp is its trigger's
    time, so the frame a port takes on the reference port's trigger k is found by
    counting trigger periods between the two ports' latest timestamps.
    """
    period_ns = period * 10
    now = {p: camera.frame(p) for p in ports}
    ref = now[ports[0]]
    offset = {
        p: now[p]["frame"]
        - round((now[p]["timestamp_ns"] - ref["timestamp_ns"]) / period_ns)
        - ref["frame"]
        for p in ports
    }
    # the newest trigger any port has seen, in the reference port's numbering
    newest = max(now[p]["frame"] - offset[p] for p in ports)
    return {p: newest + AHEAD_FRAMES + offset[p] for p in ports}


def _fetch(
    camera: CameraInterface,
    frames: Mapping[int, int],
    *,
    on_fetched: Callable[[int, int], None] | None = None,
) -> dict[int, CapturedFrame]:
    """Fetch every port's frame from the ring buffer, all at once (none is overwritten).

    ``on_fetched(port, done)`` is called (on this thread) as each frame arrives.
    """
    with ThreadPoolExecutor(max_workers=len(frames), thread_name_prefix="quad-fetch") as pool:
        futures = {pool.submit(camera.capture, p, frame=f): p for p, f in frames.items()}
        got: dict[int, CapturedFrame] = {}
        for future in as_completed(futures):
            got[futures[future]] = future.result()
            if on_fetched is not None:
                on_fetched(futures[future], len(got))
        return {p: got[p] for p in frames}


def _check_set(
    captured: Mapping[int, CapturedFrame], ports: tuple[int, ...]
) -> tuple[int, tuple[int, int], str | None]:
    """The set's common timestamp, image shape and Bayer pattern; raise if they differ."""
    stamps = {p: int(captured[p].metadata["timestamp_ns"]) for p in ports}
    ref = stamps[ports[0]]
    if len(set(stamps.values())) > 1:
        detail = ", ".join(
            f"port {p} frame {captured[p].frame} at {t} ns ({(t - ref) / 1e6:+.3f} ms)"
            for p, t in stamps.items()
        )
        raise QuadCaptureError(
            f"the four frames are not of one trigger: their timestamps differ ({detail}); "
            "allowed: one timestamp_ns for all four"
        )
    free = [p for p in ports if not int(captured[p].metadata.get("TRIG", 0)) & TRIG_SNAPSHOT]
    if free:
        raise QuadCaptureError(
            f"port(s) {', '.join(map(str, free))} took the frame in free-run "
            "(TRIG without the snapshot bit 4); another client changed the trigger meanwhile?"
        )
    shapes = {p: tuple(captured[p].image.shape) for p in ports}
    if len(set(shapes.values())) > 1:
        detail = ", ".join(f"port {p} {s[1]}x{s[0]}" for p, s in shapes.items())
        raise QuadCaptureError(f"the four images differ in size ({detail}); allowed: one size")
    bayers = {p: captured[p].metadata.get("bayer") for p in ports}
    if len(set(bayers.values())) > 1:
        detail = ", ".join(f"port {p} {b}" for p, b in bayers.items())
        raise QuadCaptureError(
            f"the four images differ in Bayer pattern ({detail}); allowed: one pattern "
            "(check FLIPH/FLIPV and the window origins)"
        )
    shape = shapes[ports[0]]
    return ref, (int(shape[0]), int(shape[1])), bayers[ports[0]]


def _manifest(
    camera: CameraInterface,
    info: Mapping[str, Any],
    layout: QuadLayout,
    captured: Mapping[int, CapturedFrame],
    *,
    master: int,
    period: int,
    bits: int,
    bayer: str | None,
) -> QuadManifest:
    per_camera = []
    for port in layout.ports:
        meta = captured[port].metadata
        per_camera.append(
            {
                "port": port,
                "sensor": meta.get("sensor"),
                "frame": captured[port].frame,
                "timestamp_ns": int(meta["timestamp_ns"]),
                "params": {k: v for k, v in meta.items() if k not in _FRAME_KEYS},
            }
        )
    first = captured[layout.ports[0]]
    capture = {
        "camera_url": camera.url,
        "board": info.get("board"),
        "daemon": f"{info.get('daemon')} {info.get('version')}",
        "frame": first.frame,
        "timestamp_ns": int(first.metadata["timestamp_ns"]),
        "trigger": {"master": master, "period_10ns": period, "mode": "snapshot"},
        "written_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    return QuadManifest(
        cameras=quad_cameras(layout.positions, per_camera),
        bayer=bayer,
        full_scale_dn=(1 << bits) - 1,
        optics=None if layout.optics is None else dict(layout.optics),
        extra={"capture": capture},
    )
