"""A guided capture's views directory: continued, reconciled with the disk, refused."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from elphel_host.calibrate.capture import (
    CaptureSessionError,
    capture_views,
    open_session,
)
from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.cli import main as elphel_main
from elphel_sim.cli import main as sim_main

PATTERN = Checkerboard(9, 6, 25.0)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("rendered") / "views"
    argv = ["calib-views", str(root), "--cameras", "1", "--views", "4", "--width", "640"]
    assert sim_main([*argv, "--height", "480", "--seed", "12"]) == 0
    return root


@pytest.fixture
def views(rendered: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(rendered, tmp_path / "views"))


def test_views_already_there_count_and_are_remembered(views: Path) -> None:
    session = open_session(views, PATTERN, cameras=1)
    assert [v.name for v in session.views] == [f"view{k:03d}.tif" for k in range(4)]
    assert all(v.seen_by == [0] for v in session.views)
    assert session.size == (640, 480) and session.next_index() == 4
    session.save()
    assert (views / "capture" / "capture.json").is_file()
    assert (views / "capture" / "coverage.png").is_file()
    (views / "view001.tif").unlink()  # removed by hand
    again = open_session(views, PATTERN, cameras=1)
    assert [v.name for v in again.views] == ["view000.tif", "view002.tif", "view003.tif"]
    before = {v.name: v.corners[0] for v in session.views if v.corners[0] is not None}
    for view in again.views:
        assert view.corners[0] is not None
        assert np.allclose(before[view.name], view.corners[0], atol=1e-3, equal_nan=True)


def test_another_pattern_or_kind_of_view_is_refused(views: Path) -> None:
    open_session(views, PATTERN, cameras=1).save()
    with pytest.raises(CaptureSessionError, match="checkerboard:9x6:25 and 1 camera"):
        open_session(views, Checkerboard(7, 4, 25.0), cameras=1)
    (views / "capture" / "capture.json").write_text("{not json")
    with pytest.raises(CaptureSessionError, match=r"not a capture state.*remove it"):
        open_session(views, PATTERN, cameras=1)
    (views / "capture" / "capture.json").unlink()
    with pytest.raises(CaptureSessionError, match=r"image files of one camera.*--quad"):
        open_session(views, PATTERN, cameras=4)


class _Frames:
    """A source of fixed images (a camera whose frames do not change)."""

    cameras = 1

    def __init__(self, image: np.ndarray) -> None:
        self.image = image

    def take(self, pending: Path) -> tuple[list[np.ndarray], str | None]:
        pending.write_bytes(b"")
        return [self.image], None

    def name(self, index: int) -> str:
        return f"view{index:03d}.tif"


def test_a_camera_of_another_size_is_refused(views: Path) -> None:
    session = open_session(views, PATTERN, cameras=1)
    with pytest.raises(CaptureSessionError, match="320x240; allowed: 640x480"):
        capture_views(_Frames(np.zeros((240, 320), np.uint16)), session, views=5)
    assert not list((views / "capture").glob("pending*"))


def test_a_frame_without_a_board_is_not_kept(views: Path) -> None:
    session = open_session(views, PATTERN, cameras=1)
    done = capture_views(
        _Frames(np.full((480, 640), 900, np.uint16)), session, views=5, attempts=2, interval_s=0
    )
    assert [a.kept for a in done] == [None, None]
    assert done[0].reason == "no 9x6 board seen" and len(session.views) == 4


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        ([], "capture needs a camera"),
        (["--camera", "http://127.0.0.1:9", "--views", "0"], "allowed at least 1"),
        (["--camera", "http://127.0.0.1:9", "--max-blur-px", "0"], "max_blur_px=0"),
        (["--camera", "http://127.0.0.1:9", "--quad", "--sensor-port", "1"], "ports 0..3"),
    ],
)
def test_capture_usage_errors_name_what_is_allowed(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    extra: list[str],
    said: str,
) -> None:
    monkeypatch.delenv("ELPHEL_CAMERA_URL", raising=False)
    argv = ["calibrate", "capture", "--pattern", PATTERN.spec, "--out", str(tmp_path / "v")]
    with pytest.raises(SystemExit) as e:
        elphel_main([*argv, *extra])
    assert e.value.code == 2 and said in capsys.readouterr().err
