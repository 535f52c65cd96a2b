"""render_strips reuses a still scene's radiance only when nothing it depends on changed.

The image formed from the reused radiance is the same uint16 array, bit for bit, as one
formed with the cache cleared; a moving plane, a moved carriage, another window or an
edited scene are misses; the cache holds to its byte bound and keeps no scene alive.
"""

import gc
import threading
import weakref
from dataclasses import replace

import numpy as np
import pytest

from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.render import RADIANCE_CACHE, Intrinsics, RadianceCache, render_strips
from elphel_sim.scenarios import build
from elphel_sim.world import Plane, Pose, Scene, Texture, World

INTRINSICS = Intrinsics(focal_length_mm=4.5, pixel_pitch_um=2.2, width=2592, height=1944)
WINDOW = (1200, 900, 64, 48)
SMALL = {"WOI_WIDTH": 96, "WOI_HEIGHT": 64, "WOI_LEFT": 1200, "WOI_TOP": 900}


def wall(**kwargs) -> Plane:
    return Plane(Texture.procedural(period_mm=400.0, seed=5, size=256), **kwargs)


def still_world() -> World:
    return World(Scene([wall(origin=(0.0, 0.0, 1000.0))], background=0.1))


def strips(world, cache, *, pose=None, window=WINDOW, times=(0.0,)):
    pose = Pose.at((0.0, 0.0, 0.0)) if pose is None else pose
    return render_strips(
        world, INTRINSICS, pose, window=window, times_s=np.array(times), cache=cache
    )


def test_board_frame_from_reused_radiance_is_bit_identical(request):
    board = SimCameraBoard(build("default", seed=1), seed=1)
    camera = CameraService(board)
    request.addfinalizer(camera.close)
    camera.set_params(0, SMALL)
    board.sim_advance(frames=4)
    RADIANCE_CACHE.clear()
    first, _ = camera.capture(0)  # renders
    hits = RADIANCE_CACHE.hits
    second, _ = camera.capture(0)  # the next frame: a still scene, same pose and window
    assert RADIANCE_CACHE.hits == hits + 1
    assert first.frame != second.frame
    assert not np.array_equal(first.image, second.image)  # each frame draws its own noise

    record = next(r for r in board.fpga[0].ring if r.frame == second.frame)
    spec, chip = board.ports[0], board.chips[0]

    def form(cache_cleared: bool) -> np.ndarray:
        if cache_cleared:
            RADIANCE_CACHE.clear()
        rng = np.random.default_rng([board.seed, 0, record.frame])
        return chip.form_image(
            record, board.world, intrinsics=spec.intrinsics, model=spec.sensor, rng=rng
        )

    uncached = form(cache_cleared=True)
    assert uncached.dtype == np.uint16
    np.testing.assert_array_equal(uncached, second.image)
    np.testing.assert_array_equal(form(cache_cleared=False), second.image)


def test_still_scene_reuses_across_strip_times_bit_for_bit():
    world, cache = still_world(), RadianceCache(max_bytes=1 << 30)
    first = strips(world, cache, times=(0.0, 0.01))
    again = strips(world, cache, times=(5.0, 5.01))
    assert (cache.hits, cache.misses) == (1, 1)
    np.testing.assert_array_equal(again, first)
    np.testing.assert_array_equal(again, strips(world, None, times=(5.0, 5.01)))
    strips(world, cache, times=(5.0, 5.01, 5.02))  # another number of strips
    assert cache.misses == 2


def test_moving_plane_is_not_reused_at_other_times():
    world = World(Scene([wall(origin=(0.0, 0.0, 1000.0), velocity_mm_s=(0.0, 500.0, 0.0))]))
    cache = RadianceCache(max_bytes=1 << 30)
    first = strips(world, cache, times=(0.0, 0.01))
    later = strips(world, cache, times=(0.02, 0.03))
    assert (cache.hits, cache.misses) == (0, 2)
    assert not np.array_equal(first, later)
    np.testing.assert_array_equal(later, strips(world, None, times=(0.02, 0.03)))


def test_moved_carriage_and_another_window_miss():
    scenario = build("default", seed=1)
    world, mount = scenario.world, scenario.ports[0].mount
    cache = RadianceCache(max_bytes=1 << 30)
    before = strips(world, cache, pose=world.camera_pose(mount))
    world.rig.carriage_mm = 0.001
    moved = strips(world, cache, pose=world.camera_pose(mount))
    assert (cache.hits, cache.misses) == (0, 2)
    assert not np.array_equal(before, moved)
    np.testing.assert_array_equal(moved, strips(world, None, pose=world.camera_pose(mount)))
    strips(world, cache, pose=world.camera_pose(mount), window=(1202, 900, 64, 48))
    assert cache.misses == 3
    strips(world, cache, pose=world.camera_pose(mount))
    assert cache.hits == 1


@pytest.mark.parametrize(
    "edit",
    [
        lambda s: s.planes.append(wall(origin=(0.0, 0.0, 500.0), half_extent_mm=(20.0, 20.0))),
        lambda s: setattr(s, "planes", [replace(s.planes[0], albedo_rgb=(0.5, 0.5, 0.5))]),
        lambda s: s.planes.__setitem__(0, replace(s.planes[0], origin=(0.0, 0.0, 900.0))),
        lambda s: setattr(s, "background", 0.2),
    ],
    ids=["plane added", "planes replaced", "plane edited", "background"],
)
def test_edited_scene_never_hits_a_stale_entry(edit):
    world, cache = still_world(), RadianceCache(max_bytes=1 << 30)
    world.scene.planes[0] = wall(origin=(0.0, 0.0, 1000.0), half_extent_mm=(40.0, 40.0))
    strips(world, cache, window=(1200, 900, 256, 256))
    edit(world.scene)
    after = strips(world, cache, window=(1200, 900, 256, 256))
    assert (cache.hits, cache.misses) == (0, 2)
    np.testing.assert_array_equal(after, strips(world, None, window=(1200, 900, 256, 256)))


def test_byte_bound_holds_least_recently_used_out_first():
    world = still_world()
    entry_bytes = 1 * 48 * 64 * 3 * 8
    cache = RadianceCache(max_bytes=2 * entry_bytes + entry_bytes // 2)
    w0, w1, w2 = [(1200 + 2 * i, 900, 64, 48) for i in range(3)]
    for w in (w0, w1, w0, w2):  # w0 used again: w1 is the least recently used
        strips(world, cache, window=w)
        assert cache.nbytes <= cache.max_bytes
    assert (len(cache), cache.nbytes, cache.hits, cache.misses) == (2, 2 * entry_bytes, 1, 3)
    strips(world, cache, window=w0)
    assert cache.hits == 2
    strips(world, cache, window=w1)  # evicted: rendered again, w2 goes
    assert (cache.hits, cache.misses, cache.nbytes) == (2, 4, 2 * entry_bytes)

    tiny = RadianceCache(max_bytes=0)  # always keeps its newest entry
    strips(world, tiny)
    strips(world, tiny)
    assert (len(tiny), tiny.hits) == (1, 1)


def test_cache_keeps_no_scene_alive_and_drops_the_entries_of_gone_planes():
    cache = RadianceCache(max_bytes=1 << 30)
    world = still_world()
    strips(world, cache)
    texture = weakref.ref(world.scene.planes[0].texture)
    del world
    gc.collect()
    assert texture() is None  # the scene's texture (and its filtered copies) went
    assert len(cache) == 1  # its radiance goes at the next put
    other = still_world()
    strips(other, cache)
    assert (len(cache), cache.nbytes) == (1, 1 * 48 * 64 * 3 * 8)
    strips(other, cache)
    assert (cache.hits, cache.misses) == (1, 2)


def test_reused_radiance_is_read_only():
    cache = RadianceCache(max_bytes=1 << 30)
    world = still_world()
    for rgb in (strips(world, cache), strips(world, cache), strips(world, None)):
        assert not rgb.flags.writeable
        with pytest.raises(ValueError):
            rgb[0, 0, 0, 0] = 1.0
    with pytest.raises(ValueError):
        strips(world, cache).flags.writeable = True


def test_threads_share_the_cache_and_get_the_same_bits():
    world, cache = still_world(), RadianceCache(max_bytes=1 << 30)
    windows = [(1200 + 2 * (i % 3), 900, 64, 48) for i in range(12)]
    expected = {w: strips(world, None, window=w) for w in set(windows)}
    results: dict[int, np.ndarray] = {}

    def work(i: int) -> None:
        results[i] = strips(world, cache, window=windows[i])

    threads = [threading.Thread(target=work, args=(i,)) for i in range(len(windows))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for i, w in enumerate(windows):
        np.testing.assert_array_equal(results[i], expected[w])
    assert len(cache) == 3 and cache.hits + cache.misses == len(windows)
