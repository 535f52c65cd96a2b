"""One trigger-synchronised set from a quad camera, written as a quad directory (DESIGN 4.4).

``elphel tp capture --camera URL --out QUAD_DIR`` then ``elphel tp QUAD_DIR --out DSI.tif``
take a quad camera from capture to DSI. The capture:

1. reads the daemon's info and requires a sensor on each of the four ports of the layout;
2. puts the four ports in snapshot mode on one common trigger (``TRIG`` 4, the same
   ``TRIG_MASTER``, no delay or decimation, ``TRIG_PERIOD`` on the master) inside
   `CameraClient.staged`, so the previous settings come back afterwards, even after an error
   (the trigger last, once no port waits for it any more);
3. waits until the change is in effect on every port, matches the ports' frame numbers
   by their timestamps (each frame of a trigger carries the trigger's time), picks a
   frame a few triggers ahead and waits until every port has taken it;
4. fetches that frame of every port from the daemon's ring buffer, checks that all four
   carry the same ``timestamp_ns``, the same size and the same Bayer pattern;
5. writes ``cam0..3.tif`` (the daemon's TIFFs, metadata included) and ``quad.json`` into
   a temporary directory next to the target and renames it into place, so a failure
   never leaves half a quad directory.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from collections.abc import Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from elphel_host.camera.client import CameraClient, CameraHTTPError, CapturedFrame
from elphel_host.errors import InputFormatError, QuadCaptureError, QuadCaptureTimeout
from elphel_host.tp.geometry import IDEAL_POSITIONS, QuadGeometry

TRIG_SNAPSHOT = 4  # TRIG bit: the sensor waits for a trigger
TRIG_PERIOD_MIN_REPEAT = 256  # TRIG_PERIOD below this stops the trigger or fires once
TICKS_PER_MS = 100_000  # TRIG_PERIOD counts 10 ns
# Slow enough that the daemon's ring buffer (64 frames) holds the set for half a minute
# while four full frames are fetched, even from a simulator rendering them.
DEFAULT_TRIGGER_PERIOD_MS = 500.0
AHEAD_FRAMES = 2  # the set is taken this many triggers after every port is synchronised

# Metadata keys that are not frame parameters (kept per camera in quad.json anyway).
_FRAME_KEYS = ("frame", "timestamp_ns", "port", "sensor", "bayer")


@dataclass(frozen=True)
class QuadLayout:
    """Which sensor port is camera i of the quad, and where camera i sits.

    Parameters
    ----------
    ports
        Sensor port of cameras 0..3.
    positions
        CameraClient centres in units of the square's side, +x right, +y down (DESIGN 4.4).
    optics
        Optional optics record copied into quad.json (``focal_length_mm``, ...).
    """

    ports: tuple[int, ...] = (0, 1, 2, 3)
    positions: tuple[tuple[float, float], ...] = IDEAL_POSITIONS
    optics: Mapping[str, Any] | None = None

    def __post_init__(self) -> None:
        if len(self.ports) != 4 or len(set(self.ports)) != 4:
            raise InputFormatError(f"ports={list(self.ports)}; allowed: four different ports")
        QuadGeometry(positions=self.positions)  # checks the positions


def read_layout(path: str | Path) -> QuadLayout:
    """A ``--geometry`` file: ``{"cameras": [{"position": [x, y], "port": P}, ...]}``.

    Four cameras in quad order; ``port`` defaults to the camera's index; an ``optics``
    object is copied into quad.json. A quad.json works as a geometry file, and so does
    the simulator's ``GET {sim_url}/quad``.

    Raises
    ------
    InputFormatError
        When the file is not JSON or does not have this form.
    """
    file = Path(path)
    try:
        doc = json.loads(file.read_text())
    except json.JSONDecodeError as e:
        raise InputFormatError(f"{file}: not valid JSON ({e})") from e
    cams = doc.get("cameras") if isinstance(doc, dict) else None
    if not isinstance(cams, list) or len(cams) != 4:
        raise InputFormatError(f"{file}: 'cameras' must list 4 cameras, got {cams!r}")
    ports: list[int] = []
    positions: list[tuple[float, float]] = []
    for i, cam in enumerate(cams):
        pos = cam.get("position") if isinstance(cam, dict) else None
        if not (
            isinstance(pos, list)
            and len(pos) == 2
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in pos)
        ):
            raise InputFormatError(
                f"{file}: cameras[{i}].position={pos!r}; allowed: [x, y] numbers"
            )
        port = cam.get("port", i)
        if not isinstance(port, int) or isinstance(port, bool) or port < 0:
            raise InputFormatError(f"{file}: cameras[{i}].port={port!r}; allowed: a port number")
        ports.append(port)
        positions.append((float(pos[0]), float(pos[1])))
    optics = doc.get("optics")
    if optics is not None and not isinstance(optics, dict):
        raise InputFormatError(f"{file}: optics={optics!r}; allowed: an object")
    return QuadLayout(ports=tuple(ports), positions=tuple(positions), optics=optics)


@dataclass(frozen=True)
class QuadCapture:
    """What `capture_quad` wrote: the directory, the frames taken and their common time."""

    path: Path
    frames: dict[int, int]
    timestamp_ns: int
    width: int
    height: int
    bayer: str | None
    manifest: dict[str, Any]


def trigger_ticks(period_ms: float) -> int:
    """``TRIG_PERIOD`` (10 ns ticks) of a repeating trigger period in milliseconds."""
    ticks = round(period_ms * TICKS_PER_MS)
    if not ticks >= TRIG_PERIOD_MIN_REPEAT:
        raise ValueError(
            f"trigger period {period_ms} ms; allowed: >= {TRIG_PERIOD_MIN_REPEAT / TICKS_PER_MS} ms"
        )
    return ticks


def capture_quad(
    camera: CameraClient,
    out: str | Path,
    *,
    layout: QuadLayout | None = None,
    trigger_period_ms: float | None = None,
    force: bool = False,
    timeout_s: float = 60.0,
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
        Period of the common trigger while capturing. None keeps the master's repeating
        period if it has one, else `DEFAULT_TRIGGER_PERIOD_MS`.
    force
        Replace an existing non-empty ``out``.
    timeout_s
        How long to wait for the ports' frames (the settings to take effect, the set).

    Returns
    -------
    QuadCapture

    Raises
    ------
    QuadCaptureError
        Too few sensor ports, frames not of one trigger (different ``timestamp_ns``),
        images of different sizes or Bayer patterns; `QuadCaptureTimeout` when the frames
        stop coming.
    FileExistsError
        ``out`` exists, is not empty and ``force`` is not set.
    CameraClientError
        The daemon refused a setting or a request (its message names the value).
    """
    layout = QuadLayout() if layout is None else layout
    target = Path(out)
    _check_target(target, force=force)
    info = camera.info()
    sensors = _quad_sensors(camera, info, layout)
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
    # The master: a port that names itself master (so TRIG_MASTER stays as it is).
    master = next((q for q in layout.ports if before[q]["TRIG_MASTER"] == q), layout.ports[0])
    if trigger_period_ms is not None:
        period = trigger_ticks(trigger_period_ms)
    elif before[master]["TRIG_PERIOD"] >= TRIG_PERIOD_MIN_REPEAT:
        period = before[master]["TRIG_PERIOD"]
    else:
        period = trigger_ticks(DEFAULT_TRIGGER_PERIOD_MS)
    deadline = time.monotonic() + timeout_s
    try:
        with _on_common_trigger(camera, before, master=master, period=period) as applied:
            # one frame past the change, so every port's latest frame is a triggered one
            _wait_for(camera, {p: f + 1 for p, f in applied.items()}, deadline, period)
            frames = _pick_frames(camera, layout.ports, period)
            _wait_for(camera, frames, deadline, period)
            captured = _fetch(camera, frames)
    except CameraHTTPError as e:
        if e.parameter != "TRIG_PERIOD":
            raise
        raise QuadCaptureError(
            f"the camera refused a {period / TICKS_PER_MS:g} ms trigger period for these "
            f"settings ({e}); give a longer one (--trigger-period-ms)"
        ) from e
    timestamp_ns, (height, width), bayer = _check_set(captured, layout.ports)
    bits = max(int(sensors[p].get("bits", 16)) for p in layout.ports)
    manifest = _manifest(
        camera, info, layout, captured, master=master, period=period, bits=bits, bayer=bayer
    )
    _write_atomically(target, captured, layout, manifest, force=force)
    return QuadCapture(
        path=target,
        frames={p: captured[p].frame for p in layout.ports},
        timestamp_ns=timestamp_ns,
        width=width,
        height=height,
        bayer=bayer,
        manifest=manifest,
    )


def _check_target(target: Path, *, force: bool) -> None:
    if force or not (target.exists() or target.is_symlink()):
        return
    if not target.is_dir():
        raise FileExistsError(f"{target} exists and is not a directory; give --force to replace it")
    if any(target.iterdir()):
        raise FileExistsError(f"{target} exists and is not empty; give --force to replace it")


def _quad_sensors(
    camera: CameraClient, info: Mapping[str, Any], layout: QuadLayout
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


def _sync_changes(
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
def _on_common_trigger(
    camera: CameraClient, before: Mapping[int, Mapping[str, int]], *, master: int, period: int
) -> Iterator[dict[int, int]]:
    """Every port in snapshot mode on the master's trigger; the old settings back after.

    The trigger starts before any port waits for it, and on the way back it is restored
    only once every port runs as before: a port still in snapshot mode when the trigger
    stops would wait forever, and its own restore with it. Yields, per port changed, the
    frame from which the change is in effect.
    """
    common, ports = _sync_changes(before, master=master, period=period)
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
    camera: CameraClient,
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


def _wait_for(
    camera: CameraClient, frames: Mapping[int, int], deadline: float, period: int
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
                f"(period {period / TICKS_PER_MS:g} ms), and is the timeout a few periods long?"
            )
        time.sleep(poll_s)


def _pick_frames(camera: CameraClient, ports: tuple[int, ...], period: int) -> dict[int, int]:
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


def _fetch(camera: CameraClient, frames: Mapping[int, int]) -> dict[int, CapturedFrame]:
    """Fetch every port's frame from the ring buffer, all at once (none is overwritten)."""
    with ThreadPoolExecutor(max_workers=len(frames), thread_name_prefix="quad-fetch") as pool:
        futures = {p: pool.submit(camera.capture, p, frame=f) for p, f in frames.items()}
        return {p: fut.result() for p, fut in futures.items()}


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
    camera: CameraClient,
    info: Mapping[str, Any],
    layout: QuadLayout,
    captured: Mapping[int, CapturedFrame],
    *,
    master: int,
    period: int,
    bits: int,
    bayer: str | None,
) -> dict[str, Any]:
    cameras = []
    for i, (port, position) in enumerate(zip(layout.ports, layout.positions, strict=True)):
        meta = captured[port].metadata
        cameras.append(
            {
                "file": f"cam{i}.tif",
                "position": list(position),
                "port": port,
                "sensor": meta.get("sensor"),
                "frame": captured[port].frame,
                "timestamp_ns": int(meta["timestamp_ns"]),
                "params": {k: v for k, v in meta.items() if k not in _FRAME_KEYS},
            }
        )
    first = captured[layout.ports[0]]
    manifest: dict[str, Any] = {
        "version": 1,
        "cameras": cameras,
        "bayer": bayer,
        "full_scale_dn": (1 << bits) - 1,
    }
    if layout.optics is not None:
        manifest["optics"] = dict(layout.optics)
    manifest["capture"] = {
        "camera_url": camera.url,
        "board": info.get("board"),
        "daemon": f"{info.get('daemon')} {info.get('version')}",
        "frame": first.frame,
        "timestamp_ns": int(first.metadata["timestamp_ns"]),
        "trigger": {"master": master, "period_10ns": period, "mode": "snapshot"},
        "written_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    return manifest


def _write_atomically(
    target: Path,
    captured: Mapping[int, CapturedFrame],
    layout: QuadLayout,
    manifest: Mapping[str, Any],
    *,
    force: bool,
) -> None:
    """Write into a temporary sibling directory and rename it onto ``target``."""
    parent = target.absolute().parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".partial", dir=parent))
    aside: Path | None = None
    try:
        for i, port in enumerate(layout.ports):
            (tmp / f"cam{i}.tif").write_bytes(captured[port].tiff)
        (tmp / "quad.json").write_text(json.dumps(manifest, indent=2) + "\n")
        _check_target(target, force=force)  # again: it may have appeared meanwhile
        if force and (target.exists() or target.is_symlink()):
            aside = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=parent))
            os.rename(target, aside / "old")
        os.rename(tmp, target)  # replaces an empty directory
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if aside is not None and (aside / "old").exists() and not target.exists():
            os.rename(aside / "old", target)  # put the old one back
        raise
    finally:
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)
