"""Frames' images formed in a child process, as a camera's sensor and FPGA form them.

The simulated board forms a frame's image when a capture asks for it: seconds of CPU for
a full frame of a scene seen for the first time, about 35 ms when its radiance is reused.
Formed in the daemon's process, that CPU and the interpreter lock are taken from the
request handling, which on a camera never does this work. `FormingProcess` does it in
one child process instead: a frame's record goes there, its pixels come back through
the pipe. The pixels are the same as formed in the daemon's process (the same chips, the
same per-frame noise seed). `SimCameraBoard(..., forming="process")` uses a `FormingPool`
of them, so that a full capture and a ring fetch asked for at once form side by side.

The child keeps its own copy of the scene. It is sent again when the scene's planes or
background change (planes compared by identity, as the radiance cache keys them);
changing a texture's array in place is not seen.

Memory is kept out of the page-fault path on both sides: the child reuses its heap for
the frame-sized arrays it makes for every frame (glibc's thresholds fixed in its
environment), and the daemon's side receives each image into a mapping of its own in
small pages (`image_buffer`). With NumPy's default (transparent huge pages asked for on
every array of 4 MiB and more) a fresh 2 MiB page can stall in the kernel's compaction:
under bench/load.py a frame's forming took 132-197 ms of CPU at the 99th percentile
instead of 33 ms, 80-180 ms of it in the kernel.
"""

from __future__ import annotations

import contextlib
import ctypes
import mmap
import os
import socket
import subprocess
import sys
import threading
from collections.abc import Hashable
from dataclasses import replace
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_camd.errors import CaptureUnavailableError
from elphel_host.parallel import MMAP_THRESHOLD_MAX
from elphel_sim.fpga import FrameRecord
from elphel_sim.scenarios import PortSpec
from elphel_sim.world import Scene, World

START_TIMEOUT_S = 120.0  # the child imports NumPy and SciPy first

# How much the children yield the CPU. The daemon mostly sleeps, so the scheduler lets it
# in as soon as a request wakes it, whatever the children's niceness; a large niceness
# only starves the children themselves beside other busy processes (at 10 they get a
# twentieth of the CPU beside two CPU-bound processes, and a capture waits for its frame
# ten times longer), so they yield a little, not all.
FORMING_NICENESS = 3

# The child's environment: its frame-sized arrays come from the heap and go back to it,
# instead of being mapped anew for every frame and their pages faulted in again, and in
# small pages (NumPy's huge-page advice off: see the module's docstring).
CHILD_ENVIRONMENT = {
    "MALLOC_MMAP_THRESHOLD_": str(MMAP_THRESHOLD_MAX),
    "MALLOC_TRIM_THRESHOLD_": str(2**30),
    "NUMPY_MADVISE_HUGEPAGE": "0",
}


#: After this long without a frame to form, the child gives its free heap back (`trim_heap`).
IDLE_TRIM_S = 5.0


def trim_heap() -> None:
    """Give the heap's free memory back to the system (glibc's ``malloc_trim``; else nothing).

    The child's heap keeps the frame-sized arrays it freed (its environment says so, see
    `CHILD_ENVIRONMENT`): fast while frames come, but after a burst it would hold the
    burst's peak for as long as the board runs.
    """
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(ctypes.c_size_t(0))


def _serve(conn: Connection, pixels: socket.socket) -> None:
    """The child: form images until the pipe closes (pixels sent raw on ``pixels``)."""
    # The sensor and FPGA never take a camera's CPU: here they yield some to the daemon.
    os.nice(FORMING_NICENESS)
    chips: dict[str, Any] = {}
    world: World | None = None
    trimmed = True
    conn.send(("ready",))
    while True:
        try:
            if not trimmed and not conn.poll(IDLE_TRIM_S):
                trim_heap()
                trimmed = True
            message = conn.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        if message[0] == "scene":
            world = World(scene=message[1])
            continue
        trimmed = False
        _form_one(conn, pixels, message[1:], world, chips)


def _form_one(
    conn: Connection,
    pixels: socket.socket,
    request: tuple[Any, ...],
    world: World | None,
    chips: dict[str, Any],
) -> None:
    """Form one frame's image in the child and send it (or the error) to the board.

    ``request`` is what the board sent: the port's spec, the frame's record and its seed.
    """
    from elphel_sim.board import SIM_SENSORS

    spec, record, seed = request
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
        return
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
        self._closed = False
        self._start()

    def _start(self) -> None:
        # A plain child interpreter (not multiprocessing's spawn, which would import the
        # parent's main script again), talking over one end of a socket pair.
        parent, child = socket.socketpair()
        self._process = subprocess.Popen(
            [sys.executable, "-m", "elphel_sim.forming", str(child.fileno())],
            pass_fds=(child.fileno(),),
            stdin=subprocess.DEVNULL,
            env={**os.environ, **CHILD_ENVIRONMENT},
        )
        child.close()
        # Messages are pickled through a Connection; the pixels come raw on the same
        # socket (`_receive_pixels`), which a Connection reads exactly up to.
        self._conn = Connection(os.dup(parent.fileno()))
        self._pixels = parent
        self._scene_key = None
        self._ready = False
        self.warm: set[Hashable] = set()  # `warm_key`s of the frames this child formed

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
            self._closed = True
            self._stop()

    def form(
        self, spec: PortSpec, record: FrameRecord, scene: Scene, seed: list[int] | None
    ) -> NDArray[Any]:
        """The image of a frame of port ``spec``, with noise seeded by ``seed`` (None: none)."""
        with self._lock:
            if self._closed:
                raise CaptureUnavailableError(f"port {record.port}: the board is closed")
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
        key = scene_key(scene)
        if key != self._scene_key:
            conn.send(("scene", scene))
            self._scene_key, self._scene_planes = key, tuple(scene.planes)
        conn.send(("form", spec, replace(record, image=None), seed))
        answer = conn.recv()
        if answer[0] == "error":
            raise CaptureUnavailableError(
                f"port {record.port}: forming frame {record.frame} failed: {answer[1]}"
            )
        _, shape, dtype = answer
        image = image_buffer(shape, np.dtype(dtype))
        _receive_pixels(pixels, image)
        self.warm.add(warm_key(spec, record, scene))
        return image


def scene_key(scene: Scene) -> tuple[Any, ...]:
    """What tells a scene from a changed one: its planes' identities and background."""
    return (tuple(id(p) for p in scene.planes), np.float64(float(scene.background)).tobytes())


def warm_key(spec: PortSpec, record: FrameRecord, scene: Scene) -> Hashable:
    """A child that formed a frame of this key has the radiance the next one reuses."""
    return (scene_key(scene), record.port, spec.model)


#: Images from this size up get a memory mapping of their own (`image_buffer`).
IMAGE_MMAP_BYTES = 4 * 2**20


def image_buffer(shape: tuple[int, ...], dtype: np.dtype[Any]) -> NDArray[Any]:
    """An empty image; from `IMAGE_MMAP_BYTES` up in an anonymous mapping of its own.

    The board keeps each formed frame's pixels (10 MB at full resolution) on its ring
    record until the frame leaves the 64-frame ring. From glibc's heap, freed images
    left holes the heap could not give back (under bench/load.py the daemon's RSS grew
    26 % after minute 2); in a mapping of its own an image's memory goes back to the
    system when it is freed. Its pages are small ones (NumPy would ask for huge pages,
    whose faults can stall).
    """
    nbytes = int(np.prod(shape)) * dtype.itemsize
    if nbytes < IMAGE_MMAP_BYTES:
        return np.empty(shape, dtype=dtype)
    memory = mmap.mmap(-1, nbytes)
    with contextlib.suppress(AttributeError, OSError):  # the advice exists on Linux only
        memory.madvise(mmap.MADV_NOHUGEPAGE)
    return np.frombuffer(memory, dtype=dtype).reshape(shape)


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


class FormingPool:
    """Up to ``size`` `FormingProcess` children: frames asked for at once form side by side.

    A frame goes to a free child that has formed one of its scene and port before (a
    *warm* child: it reuses the radiance, tens of milliseconds for a full frame). While
    every warm child is busy the frame waits for one rather than going to a cold child
    (seconds for a full frame: a new child boots and renders the radiance from scratch),
    and a cold child is warmed meanwhile with the same frame, so that frames asked for at
    once next time form side by side. Children start on demand (one capture at a time
    never starts a second).
    """

    def __init__(self, size: int = 2) -> None:
        if size < 1:
            raise ValueError(f"size={size}; allowed: >= 1")
        self.size = size
        self._cond = threading.Condition()
        self._free: list[FormingProcess] = []
        self._all: list[FormingProcess] = []
        self._warming: set[Hashable] = set()  # keys a child is being warmed for

    @property
    def processes(self) -> list[FormingProcess]:
        with self._cond:
            return list(self._all)

    def form(
        self, spec: PortSpec, record: FrameRecord, scene: Scene, seed: list[int] | None
    ) -> NDArray[Any]:
        """As `FormingProcess.form`, in a warm child if there is one (see the class)."""
        key = warm_key(spec, record, scene)
        with self._cond:
            while True:
                former = self._take(key)
                if former is not None:
                    break
                self._warm_another(key, spec, record, scene)
                self._cond.wait()
        try:
            return former.form(spec, record, scene, seed)
        finally:
            self._give_back(former)

    def _take(self, key: Hashable) -> FormingProcess | None:
        """A child for a frame of ``key`` now, or None: wait for a warm one (lock held)."""
        for former in reversed(self._free):
            if key in former.warm:
                self._free.remove(former)
                return former
        if any(key in former.warm for former in self._all):
            return None  # busy now, free within one frame's forming
        return self._cold()

    def _cold(self) -> FormingProcess | None:
        """A free child or a new one, if the pool has one to give (lock held)."""
        if self._free:
            return self._free.pop()
        if len(self._all) < self.size:
            former = FormingProcess()
            self._all.append(former)
            return former
        return None

    def _give_back(self, former: FormingProcess) -> None:
        with self._cond:
            self._free.append(former)
            self._cond.notify_all()

    def _warm_another(
        self, key: Hashable, spec: PortSpec, record: FrameRecord, scene: Scene
    ) -> None:
        """Warm a cold child for ``key`` in the background, if none is warming (lock held)."""
        if key in self._warming:
            return
        former = self._cold()
        if former is None:
            return
        self._warming.add(key)

        def warm() -> None:
            try:
                with contextlib.suppress(CaptureUnavailableError):
                    former.form(spec, record, scene, None)  # noise-free: the radiance counts
            finally:
                with self._cond:
                    self._warming.discard(key)
                self._give_back(former)

        threading.Thread(target=warm, name="sim-forming-warm-up", daemon=True).start()

    def close(self) -> None:
        for former in self.processes:
            former.close()


if __name__ == "__main__":
    _fd = int(sys.argv[1])
    _serve(Connection(os.dup(_fd)), socket.socket(fileno=_fd))
