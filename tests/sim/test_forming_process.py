"""Images formed in a child process (`SimCameraBoard(..., forming="process")`).

The daemon's simulated board forms images there so that their CPU is not taken from the
daemon's request handling. The pixels must be the ones formed in the capturing thread;
a scene changed after the child started must be seen; a child that died must not take
the board down with it.
"""

import os
import signal
import threading
import time

import numpy as np
import pytest

from elphel_camd.errors import CaptureUnavailableError
from elphel_sim.board import SimCameraBoard, make_sim_board
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
