"""Frames' images formed in a child process, as a camera's sensor and FPGA form them.

The simulated board forms a frame's image when a capture asks for it: seconds of CPU for
a full frame of a scene seen for the first time, about 0.15 s when its radiance is reused.
Formed in the daemon's process, that CPU and the interpreter lock are taken from the
request handling, which on a camera never does this work. `FormingProcess` does it in
one child process instead: a frame's record goes there, its pixels come back through
the pipe. The pixels are the same as formed in the daemon's process (the same chips, the
same per-frame noise seed). `SimCameraBoard(..., forming="process")` uses a `FormingPool`
of them, so that a full capture and a ring fetch asked for at once form side by side.

The child keeps its own copy of the scene. It is sent again when the scene's planes or
background change (planes compared by identity, as the radiance cache keys them);
changing a texture's array in place is not seen.
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import threading
from dataclasses import replace
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_camd.errors import CaptureUnavailableError
from elphel_host.parallel import fix_mmap_threshold
from elphel_sim.fpga import FrameRecord
from elphel_sim.scenarios import PortSpec
from elphel_sim.world import Scene, World

START_TIMEOUT_S = 120.0  # the child imports NumPy and SciPy first


def _serve(conn: Connection, pixels: socket.socket) -> None:
    """The child: form images until the pipe closes (pixels sent raw on ``pixels``)."""
    from elphel_sim.board import SIM_SENSORS

    # The sensor and FPGA never take a camera's CPU: here they yield it to the daemon.
    os.nice(10)
    chips: dict[str, Any] = {}
    world: World | None = None
    conn.send(("ready",))
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        if message[0] == "scene":
            world = World(scene=message[1])
            continue
        _, spec, record, seed = message
        try:
            if world is None:
                raise RuntimeError("no scene was sent")
            chip = chips.get(spec.model) or chips.setdefault(spec.model, SIM_SENSORS[spec.model]())
            rng = None if seed is None else np.random.default_rng(seed)
            image = np.ascontiguousarray(
                chip.form_image(record, world, rng=rng, **spec.forming_options())
            )
        except Exception as e:  # reported to the board, which raises it for the capture
            conn.send(("error", f"{type(e).__name__}: {e}"))
            continue
        conn.send(("image", image.shape, image.dtype.str))
        pixels.sendall(image.data.cast("B"))


class FormingProcess:
    """One child process forming the images of a board's frames, one at a time.

    Started at once (the child boots while the daemon does); a child that died is started
    again at the next frame. Safe to call from several threads: they take turns.
    """

    @property
    def pid(self) -> int | None:
        """The child's process id (None while none runs)."""
        return None if self._process is None else self._process.pid

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._conn: Connection | None = None
        self._pixels: socket.socket | None = None
        self._process: subprocess.Popen[bytes] | None = None
        self._scene_key: tuple[Any, ...] | None = None
        self._scene_planes: tuple[object, ...] = ()  # held so that their ids stay theirs
        self._start()

    def _start(self) -> None:
        # A plain child interpreter (not multiprocessing's spawn, which would import the
        # parent's main script again), talking over one end of a socket pair.
        parent, child = socket.socketpair()
        self._process = subprocess.Popen(
            [sys.executable, "-m", "elphel_sim.forming", str(child.fileno())],
            pass_fds=(child.fileno(),),
            stdin=subprocess.DEVNULL,
        )
        child.close()
        # Messages are pickled through a Connection; the pixels come raw on the same
        # socket (`_receive_pixels`), which a Connection reads exactly up to.
        self._conn = Connection(os.dup(parent.fileno()))
        self._pixels = parent
        self._scene_key = None
        self._ready = False

    def _stop(self) -> None:
        if self._conn is not None:
            with contextlib.suppress(OSError):
                self._conn.send(None)
            self._conn.close()
        if self._pixels is not None:
            self._pixels.close()
        if self._process is not None:
            try:
                self._process.wait(timeout=2)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait(timeout=2)
        self._conn = self._pixels = self._process = None

    def close(self) -> None:
        with self._lock:
            self._stop()

    def form(
        self, spec: PortSpec, record: FrameRecord, scene: Scene, seed: list[int] | None
    ) -> NDArray[Any]:
        """The image of a frame of port ``spec``, with noise seeded by ``seed`` (None: none)."""
        with self._lock:
            if self._conn is None or self._process is None or self._process.poll() is not None:
                self._stop()
                self._start()
            assert self._conn is not None and self._pixels is not None
            try:
                return self._form(self._conn, self._pixels, spec, record, scene, seed)
            except (EOFError, OSError) as e:
                self._stop()
                raise CaptureUnavailableError(
                    f"port {record.port}: the image-forming process ended while forming "
                    f"frame {record.frame} ({type(e).__name__}); it restarts at the next frame"
                ) from e

    def _form(
        self,
        conn: Connection,
        pixels: socket.socket,
        spec: PortSpec,
        record: FrameRecord,
        scene: Scene,
        seed: list[int] | None,
    ) -> NDArray[Any]:
        if not self._ready:
            if not conn.poll(START_TIMEOUT_S):
                raise EOFError("the image-forming process did not start")
            conn.recv()
            self._ready = True
        planes = tuple(scene.planes)
        key = (tuple(id(p) for p in planes), np.float64(float(scene.background)).tobytes())
        if key != self._scene_key:
            conn.send(("scene", scene))
            self._scene_key, self._scene_planes = key, planes
        conn.send(("form", spec, replace(record, image=None), seed))
        answer = conn.recv()
        if answer[0] == "error":
            raise CaptureUnavailableError(
                f"port {record.port}: forming frame {record.frame} failed: {answer[1]}"
            )
        _, shape, dtype = answer
        image = np.empty(shape, dtype=np.dtype(dtype))
        _receive_pixels(pixels, image)
        return image


def _receive_pixels(sock: socket.socket, image: NDArray[Any]) -> None:
    """Fill ``image`` from the socket, the kernel copying straight into its buffer.

    Each ``recv_into`` lets go of the interpreter lock while it copies. A Connection's
    ``recv_bytes_into`` copies 10 MB through Python buffers holding the lock instead:
    while it did, another thread's 1 ms sleep woke up to 28-66 ms late (p99 4-5 ms; here
    0.4-0.6 ms), and that other thread is the daemon's event loop.
    """
    view = image.reshape(-1).view(np.uint8).data
    got = 0
    while got < len(view):
        n = sock.recv_into(view[got:])
        if n == 0:
            raise EOFError(f"the image-forming process closed after {got} of {len(view)} bytes")
        got += n


#: Arrays from this size up get their own memory mapping in the process that keeps the
#: formed images (see `_images_in_their_own_mappings`).
IMAGE_MMAP_BYTES = 4 * 2**20


def _images_in_their_own_mappings() -> None:
    """Fix glibc's mmap threshold at `IMAGE_MMAP_BYTES` in this process.

    The board keeps each formed frame's pixels (10 MB at full resolution) on its ring
    record until the frame leaves the 64-frame ring. With glibc's dynamic threshold, the
    first freed image raises the threshold above the image size, later images come from
    the heap, and freed ones leave holes the heap cannot give back: under bench/load.py
    the daemon's RSS grew 26 % after minute 2. Mapped on their own, freed images go back
    to the system at once.
    """
    fix_mmap_threshold(IMAGE_MMAP_BYTES)


class FormingPool:
    """Up to ``size`` `FormingProcess` children: frames asked for at once form side by side.

    A child is started when every started one is busy (one capture at a time uses one).
    The pool's process keeps large arrays in their own mappings
    (`_images_in_their_own_mappings`).
    """

    def __init__(self, size: int = 2) -> None:
        if size < 1:
            raise ValueError(f"size={size}; allowed: >= 1")
        _images_in_their_own_mappings()
        self.size = size
        self._lock = threading.Lock()
        self._free: list[FormingProcess] = []
        self._all: list[FormingProcess] = []
        self._available = threading.Semaphore(size)

    @property
    def processes(self) -> list[FormingProcess]:
        with self._lock:
            return list(self._all)

    def form(
        self, spec: PortSpec, record: FrameRecord, scene: Scene, seed: list[int] | None
    ) -> NDArray[Any]:
        """As `FormingProcess.form`, in a child that is free now."""
        with self._available:
            with self._lock:
                if self._free:
                    former = self._free.pop()
                else:
                    former = FormingProcess()
                    self._all.append(former)
            try:
                return former.form(spec, record, scene, seed)
            finally:
                with self._lock:
                    self._free.append(former)

    def close(self) -> None:
        for former in self.processes:
            former.close()


if __name__ == "__main__":
    _fd = int(sys.argv[1])
    _serve(Connection(os.dup(_fd)), socket.socket(fileno=_fd))
