"""Messages a newcomer meets for a wrong URL, a wrong directory or a wrong option value.

Each says what was wrong and what to give instead, quickly, in the CLI's terms.
"""

from __future__ import annotations

import json
import re
import socket
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile

from elphel_host.cli import main


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_camera_urls_in_other_spellings(elphel_rig, capsys) -> None:
    token = ["--token", elphel_rig.token]
    host_port = elphel_rig.camera_url.removeprefix("http://")
    for url in (f"{elphel_rig.camera_url}/api/v1", f"{elphel_rig.camera_url}/api/v1/", host_port):
        code, out, err = run(capsys, "camera", "info", "--camera", url, *token, "--json")
        assert code == 0, err
        assert json.loads(out)["ports"]


def test_wrong_camera_urls_say_what_to_give(elphel_rig, capsys) -> None:
    code, _, err = run(capsys, "camera", "info", "--camera", elphel_rig.sim_url)
    assert code == 1 and "is not elphel-camd" in err and "camera_url, not sim_url" in err
    stage_port = elphel_rig.stage_url.rsplit(":", 1)[1]
    t0 = time.monotonic()
    code, _, err = run(capsys, "camera", "info", "--camera", f"http://127.0.0.1:{stage_port}")
    assert code == 1 and "gave no HTTP answer within 5 s" in err
    assert time.monotonic() - t0 < 8.0


def test_silent_port_fails_quickly(capsys) -> None:
    with socket.socket() as silent:  # accepts connections, never answers
        silent.bind(("127.0.0.1", 0))
        silent.listen(1)
        url = f"http://127.0.0.1:{silent.getsockname()[1]}"
        t0 = time.monotonic()
        code, _, err = run(capsys, "camera", "info", "--camera", url)
    assert code == 1 and "gave no HTTP answer" in err and time.monotonic() - t0 < 8.0


def test_watch_on_a_stock_nc393_speaks_cli(capsys) -> None:
    code, _, err = run(capsys, "camera", "watch", "--camera", "nc393://127.0.0.1:9")
    assert code == 1 and "elphel camera get FRAME" in err and "()" not in err


def quad_directory(root: Path) -> Path:
    cams = []
    for i, pos in enumerate([[-0.5, -0.5], [0.5, -0.5], [-0.5, 0.5], [0.5, 0.5]]):
        tifffile.imwrite(root / f"cam{i}.tif", np.zeros((32, 32), np.uint16))
        cams.append({"file": f"cam{i}.tif", "position": pos})
    (root / "quad.json").write_text(json.dumps({"version": 1, "cameras": cams, "bayer": None}))
    return root


def test_depth_on_a_quad_directory_asks_for_a_quad_burst(tmp_path, capsys) -> None:
    quad = quad_directory(tmp_path)
    code, _, err = run(capsys, "depth", str(quad), "--out", str(tmp_path / "d"))
    assert code == 1 and "is a quad directory" in err and "needs a quad burst" in err
    assert "elphel burst capture --quad" in err


@pytest.mark.parametrize("command", ["mfsr", "depth"])
def test_bad_scale_is_a_usage_error_everywhere(command, tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main([command, str(tmp_path), "--scale", "9", "--out", str(tmp_path / "o")])
    assert info.value.code == 2
    assert "scale='9'; allowed: an integer 1..8" in capsys.readouterr().err


def test_capture_and_params_read_plainly(elphel_rig, tmp_path, capsys) -> None:
    cam = ["--camera", elphel_rig.camera_url, "--token", elphel_rig.token]
    code, out, err = run(capsys, "camera", "params", *cam)
    assert code == 0, err
    lines = out.splitlines()
    header = lines[1]
    assert header.split() == ["NAME", "VALUE", "UNIT", "RANGE", "MEANING"]
    rows = {line.split()[0]: line for line in lines[2:]}
    assert rows["WOI_WIDTH"].index("2..2592 (even)") == header.index("RANGE")
    assert rows["WOI_WIDTH"].index("pixels") == header.index("UNIT")
    assert "0 or 2..1944 (even)" in rows["PF_HEIGHT"]  # 0: photo-finish off
    assert re.search(r"\s0\.\.3\s", rows["FPSFLAGS"])
    tif, png = tmp_path / "f.tif", tmp_path / "f.png"
    code, out, err = run(capsys, "camera", "capture", *cam, "--out", str(tif), "--png", str(png))
    assert code == 0, err
    assert png.is_file() and out.strip().endswith(f"-> {tif}; preview {png}")


def test_sim_announcement_shows_no_none(capsys) -> None:
    from elphel_sim.launcher import print_announcement

    announce = {
        "camera_url": "nc393://127.0.0.1:8080?imgsrv=2323",
        "token": None,
        "stage_url": "socket://127.0.0.1:2000",
        "lens_blur_px": 0.0,
        "lens_blur_edge_px": None,
    }
    print_announcement(announce, scenario="default", seed=0)
    out = capsys.readouterr().out
    assert "None" not in out and "lens_blur_px" in out and "lens_blur_edge_px" not in out
