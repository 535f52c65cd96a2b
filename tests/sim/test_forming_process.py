"""Images formed in a child process (`SimCameraBoard(..., forming="process")`).

The daemon's simulated board forms images there so that their CPU is not taken from the
daemon's request handling. The pixels must be the ones formed in the capturing thread;
a scene changed after the child started must be seen; a child that died must not take
the board down with it.
"""

import mmap
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from elphel_camd.errors import CaptureUnavailableError
from elphel_sim.board import SimCameraBoard, make_sim_board
from elphel_sim.forming import CHILD_ENVIRONMENT, FormingProcess, image_buffer
from elphel_sim.scenarios import build

LEPTON = 2  # the mixed scenario's 160x120 Lepton: quick to form


@pytest.fixture(scope="module")
def boards():  # shared: each test leaves both boards in the same state
    here = SimCameraBoard(build("mixed", seed=4), seed=4)
    there = SimCameraBoard(build("mixed", seed=4), seed=4, forming="process")
    yield here, there
    here.close()
    there.close()


def test_the_same_pixels_as_formed_in_the_thread(boards):
    here, there = boards
    for _ in range(2):
        a, b = here.capture(LEPTON), there.capture(LEPTON)
        assert a.frame == b.frame
        assert b.image.dtype == a.image.dtype and b.image.flags.writeable
        np.testing.assert_array_equal(b.image, a.image)


def test_a_changed_scene_is_sent_again(boards):
    here, there = boards
    here.capture(LEPTON)
    first = there.capture(LEPTON).image
    for board in boards:
        board.world.scene.planes.pop()
    a, b = here.capture(LEPTON), there.capture(LEPTON)
    assert a.frame == b.frame
    np.testing.assert_array_equal(b.image, a.image)
    assert np.abs(b.image.astype(int) - first).mean() > 100  # not just other noise


def test_a_child_dead_between_frames_is_started_again(boards):
    _, there = boards
    there.capture(LEPTON)
    (former,) = there._former.processes
    child = former._process
    os.kill(child.pid, signal.SIGKILL)
    child.wait(timeout=10)
    assert there.capture(LEPTON).image.shape == (120, 160)
    assert there._former.processes == [former] and former.pid != child.pid


def test_a_child_dying_while_it_forms_fails_that_capture_only():
    board = SimCameraBoard(build("default", seed=4), seed=4, forming="process")
    try:
        outcome = {}

        def capture():
            try:
                board.capture(0)
            except CaptureUnavailableError as e:
                outcome["error"] = str(e)

        worker = threading.Thread(target=capture)
        worker.start()
        time.sleep(1.0)  # a full frame of a new scene takes seconds to form
        (former,) = board._former.processes
        child = former._process
        os.kill(child.pid, signal.SIGKILL)
        worker.join(timeout=60)
        assert "port 0" in outcome["error"] and "image-forming process ended" in outcome["error"]
    finally:
        board.close()


def test_close_ends_the_child():
    board = SimCameraBoard(build("mixed", seed=4), seed=4, forming="process")
    assert board._former.processes == []  # started at the first frame formed
    board.capture(LEPTON)
    (former,) = board._former.processes
    child = former._process
    board.close()
    assert child.poll() is not None


def test_frames_asked_for_at_once_form_in_two_children_at_most(boards):
    here, there = boards
    wanted = [there.fpga[LEPTON].frame + k for k in (1, 2, 3, 4)]
    there.sim_advance(frames=5, port=LEPTON)
    here.sim_advance(frames=5, port=LEPTON)
    barrier = threading.Barrier(len(wanted))
    got = {}

    def capture(frame):
        barrier.wait()
        got[frame] = there.capture(LEPTON, frame=frame).image

    threads = [threading.Thread(target=capture, args=(f,)) for f in wanted]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert len(there._former.processes) == 2
    for frame in wanted:
        np.testing.assert_array_equal(got[frame], here.capture(LEPTON, frame=frame).image)


def test_the_daemons_board_forms_in_a_child_and_unknown_modes_are_refused():
    board = make_sim_board(scenario="mixed")
    try:
        assert board._former is not None
    finally:
        board.close()
    with pytest.raises(ValueError, match="allowed: thread, process"):
        SimCameraBoard(build("mixed", seed=4), forming="gpu")


def test_a_frame_waits_for_a_warm_child_while_a_cold_one_is_warmed(monkeypatch):
    # A cold child boots and renders the radiance from scratch (seconds for a full frame):
    # a frame asked for while the only warm child is busy waits for that child instead,
    # and a second child is warmed meanwhile for the next frames asked for together.
    board = SimCameraBoard(build("mixed", seed=4), seed=4, forming="process")
    try:
        board.capture(LEPTON)
        (warm,) = board._former.processes
        slow = threading.Event()
        form = FormingProcess.form
        calls = []  # (child, frame, a capture's (seeded) or a warm-up's (noise-free))

        def form_slowly(self, spec, record, scene, seed):
            calls.append((self, record.frame, seed is not None))
            if self is warm and not slow.is_set():
                slow.set()
                time.sleep(1.0)  # busy: the next capture comes meanwhile
            return form(self, spec, record, scene, seed)

        monkeypatch.setattr(FormingProcess, "form", form_slowly)
        first = threading.Thread(target=board.capture, args=(LEPTON,))
        first.start()
        assert slow.wait(10)
        board.sim_advance(frames=1, port=LEPTON)
        got = board.capture(LEPTON)  # while the warm child is still busy
        first.join(timeout=30)
        assert got.image.shape == (120, 160)
        cold = next(f for f in board._former.processes if f is not warm)
        assert LEPTON in {key[1] for key in warm.warm}
        deadline = time.monotonic() + 60
        while not cold.warm and time.monotonic() < deadline:
            time.sleep(0.05)
        assert {key[1] for key in cold.warm} == {LEPTON}  # warmed with the same port's frame
        # the cold child's first frame was its warm-up; a capture came to it warm or never
        assert next(seeded for child, _, seeded in calls if child is cold) is False
        assert len(board._former.processes) == 2
    finally:
        board.close()


def test_memory_stays_out_of_the_page_fault_path(boards):
    # The child reuses its heap and asks for no huge pages; the daemon's side receives a
    # full frame into a mapping of its own (freed with the image), in small pages.
    _, there = boards
    there.capture(LEPTON)
    former = there._former.processes[0]
    environ = dict(
        item.split("=", 1)
        for item in Path(f"/proc/{former.pid}/environ").read_text().split("\0")
        if "=" in item
    )
    assert {k: environ.get(k) for k in CHILD_ENVIRONMENT} == CHILD_ENVIRONMENT
    full = image_buffer((1944, 2592), np.dtype(np.uint16))
    assert full.shape == (1944, 2592) and full.flags.writeable and full.flags.c_contiguous
    assert isinstance(full.base.base.obj, mmap.mmap)  # a view of a memoryview of the mapping
    small = image_buffer((120, 160), np.dtype(np.uint16))
    assert small.base is None and small.shape == (120, 160)
