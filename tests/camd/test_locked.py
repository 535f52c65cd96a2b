"""The parameter routes' work under a port's locks: on the event loop when it is free.

`run_locked` must never make the event loop block on a lock held elsewhere (a frame sync
programming the sensor over a slow I2C bus): it tries again while the loop goes on, and
hands the work to a thread when the lock stays held. It releases what it took.
"""

import asyncio
import threading
import time

import pytest

from elphel_camd.api import locked
from elphel_camd.api.locked import run_locked
from elphel_camd.store import ParamStore


def test_free_locks_run_the_work_on_the_loop():
    locks = [threading.RLock(), threading.RLock()]

    async def main():
        loop_thread = threading.get_ident()
        ran_in = await run_locked(locks, threading.get_ident)
        return loop_thread, ran_in

    loop_thread, ran_in = asyncio.run(main())
    assert ran_in == loop_thread
    for lock in locks:  # released
        assert lock.acquire(blocking=False)
        lock.release()


def test_a_lock_held_briefly_is_waited_for_on_the_loop(monkeypatch):
    # A wait bound far above the holder's 5 ms: a loaded test machine cannot turn it
    # into a thread hand-off.
    monkeypatch.setattr(locked, "LOOP_WAIT_S", 2.0)
    held = threading.RLock()
    taken = threading.Event()

    def holder():
        with held:
            taken.set()
            time.sleep(0.005)  # a frame sync programming the sensor

    threading.Thread(target=holder, daemon=True).start()
    taken.wait(5)

    async def main():
        loop_thread = threading.get_ident()
        ran_in = await run_locked([held], threading.get_ident)
        return loop_thread, ran_in

    loop_thread, ran_in = asyncio.run(main())
    assert ran_in == loop_thread
    assert held.acquire(blocking=False)


def test_a_held_lock_sends_the_work_to_a_thread_and_the_loop_goes_on():
    free, held = threading.RLock(), threading.RLock()
    taken, release = threading.Event(), threading.Event()

    def holder():
        with held:
            taken.set()
            release.wait(5)

    threading.Thread(target=holder, daemon=True).start()
    taken.wait(5)

    async def main():
        loop_thread = threading.get_ident()
        work = asyncio.create_task(run_locked([free, held], threading.get_ident))
        ticks = 0
        for _ in range(20):  # the loop keeps running while the work waits for the lock
            await asyncio.sleep(0.01)
            ticks += 1
        assert not work.done()
        release.set()
        return loop_thread, await work, ticks

    loop_thread, ran_in, ticks = asyncio.run(main())
    assert ticks == 20 and ran_in != loop_thread


def test_work_that_waits_for_a_device_goes_to_a_thread():
    async def main():
        return threading.get_ident(), await run_locked(
            [threading.Lock()], threading.get_ident, on_loop=False
        )

    loop_thread, ran_in = asyncio.run(main())
    assert ran_in != loop_thread


@pytest.mark.parametrize("on_loop", [True, False])
def test_an_error_propagates_and_the_locks_are_released(on_loop):
    lock = threading.Lock()

    def fail():
        raise ValueError("refused")

    with pytest.raises(ValueError, match="refused"):
        asyncio.run(run_locked([lock], fail, on_loop=on_loop))
    assert lock.acquire(blocking=False)


def test_a_save_does_not_wait_for_a_compaction_flushing_to_the_disk(tmp_path, monkeypatch):
    # The compaction's flushes happen without the port's lock: a PATCH saving meanwhile
    # (on the event loop) must not wait for the disk.
    from elphel_camd import store as store_module

    store = ParamStore(tmp_path)
    store.save(0, "MT9P006", {"EXPOS": 1})
    compactor = threading.current_thread()
    real_fsync = store_module.os.fsync
    in_fsync = threading.Event()

    def slow_fsync(fd):
        if threading.current_thread() is compactor:
            in_fsync.set()
            time.sleep(0.5)
        real_fsync(fd)

    monkeypatch.setattr(store_module.os, "fsync", slow_fsync)
    compactor = threading.Thread(target=store._compact, args=(0,))
    compactor.start()
    saves = []
    deadline = time.monotonic() + 5
    while compactor.is_alive() and time.monotonic() < deadline:
        if in_fsync.is_set():
            t0 = time.perf_counter()
            store.save(0, "MT9P006", {"EXPOS": 2 + len(saves)})
            saves.append(time.perf_counter() - t0)
        time.sleep(0.02)
    compactor.join()
    monkeypatch.setattr(store_module.os, "fsync", real_fsync)
    store.close()
    assert saves and max(saves) < 0.2, saves
    with ParamStore(tmp_path) as fresh:
        assert fresh.load(0, "MT9P006") == {"EXPOS": 1 + len(saves)}
