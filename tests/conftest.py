"""Settings every test shares, and the check that a test closes what it opens."""

from __future__ import annotations

import gc
import threading
import time
import weakref
from collections.abc import Iterator

import pytest

from elphel_sim.board import SimCameraBoard


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the tests marked ``slow`` first, each group in its collection order.

    With pytest-xdist, a long test that starts last leaves the other workers idle until it
    ends; started first, it runs beside the many short ones (make test hands the tests out
    one at a time, ``--maxschedchunk 1``, so the long ones go to different workers).
    """
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


# How long a thread a test started may take to end after the test (a pool told to shut
# down without waiting, a reader noticing its stream closed).
THREAD_GRACE_S = 2.0

# Boards built since the running test began (weakly: a board that is gone is no leak).
_boards_built: list[weakref.ref[SimCameraBoard]] = []


@pytest.fixture(autouse=True)
def _private_config_home(tmp_path_factory: pytest.TempPathFactory, monkeypatch) -> None:
    """Keep stage calibrations and other settings out of the user's ~/.config."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path_factory.mktemp("config")))


@pytest.fixture(autouse=True, scope="session")
def _count_boards_built() -> Iterator[None]:
    """Note every simulated board built, so that `_closes_what_it_opens` can check it."""
    build = SimCameraBoard.__init__

    def noted(self: SimCameraBoard, *args: object, **kwargs: object) -> None:
        build(self, *args, **kwargs)  # type: ignore[arg-type]
        _boards_built.append(weakref.ref(self))

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(SimCameraBoard, "__init__", noted)
        yield


@pytest.fixture(autouse=True)
def _closes_what_it_opens(_count_boards_built: None) -> Iterator[None]:
    """Fail a test that leaves a simulated board open, or a thread running beside a board.

    An open board keeps its frames (hundreds of MB) and its daemon service alive, and a
    worker that runs hundreds of such tests runs the machine out of memory. Autouse
    fixtures are set up before the test's own and torn down after them; boards and
    threads of wider-scoped fixtures exist before this one starts and are not counted.
    """
    _boards_built.clear()
    threads_before = set(threading.enumerate())
    yield
    built = len(_boards_built)
    still_open = sum(1 for ref in _boards_built if _is_open(ref))
    _boards_built.clear()
    threads = _threads_still_running(threads_before)
    if built:
        # A closed board and its service, app and scene stay in reference cycles (the
        # FastAPI app, the service and its capture helpers refer to each other) until a
        # full collection, which comes rarely in a process holding as many objects as a
        # test worker: collect them now, with their textures and filtered copies.
        gc.collect()
    if still_open or (built and threads):
        pytest.fail(
            f"the test left {still_open} simulated board(s) open and these threads it "
            f"started running: {sorted(t.name for t in threads)}; close the service, board "
            "or client it opened (a fixture that yields and closes, or a with-block)"
        )


def _is_open(ref: weakref.ref[SimCameraBoard]) -> bool:
    board = ref()
    return board is not None and not board.closed


def _threads_still_running(before: set[threading.Thread]) -> list[threading.Thread]:
    """Threads started since ``before`` that are still alive after `THREAD_GRACE_S`.

    A worker thread of an event loop that was running before belongs to that loop and
    ends with it: AnyIO's (a module-scoped client's portal) and the default executor's
    ``asyncio_N`` threads (Playwright's loop, open for the browser tests' package); dask's
    offload thread is one for the process.
    """
    deadline = time.monotonic() + THREAD_GRACE_S
    portal_before = any(t.name.startswith("asyncio-portal") and t.is_alive() for t in before)
    left = [
        t
        for t in threading.enumerate()
        if t not in before
        and not (portal_before and t.name == "AnyIO worker thread")
        and not t.name.startswith(("asyncio_", "Dask-Offload"))
    ]
    for thread in left:
        thread.join(timeout=max(0.0, deadline - time.monotonic()))
    return [t for t in left if t.is_alive()]
