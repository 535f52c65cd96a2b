from __future__ import annotations

import importlib.util
import json
import os

import numpy as np
import pytest
import tifffile
from PIL import Image

from elphel_host.burst.io import write_burst
from elphel_host.cli import main
from elphel_host.mfsr.cli import crop_label


def _burst(tmp_path, burst2):
    frames, _ = burst2
    dn = [np.clip(np.rint(f * 4000), 0, 65535).astype(np.uint16) for f in frames[:8]]
    return write_burst(tmp_path / "b", dn)


def test_mfsr_json_is_one_object(tmp_path, burst2, capsys):
    b = _burst(tmp_path, burst2)
    out = tmp_path / "o" / "sr.tif"
    assert main(["mfsr", str(b), "--scale", "2", "--out", str(out), "--json"]) == 0
    captured = capsys.readouterr()
    result = json.loads(captured.out)
    assert captured.err == f"mfsr: fusing {b} (robust x2)\n"  # not silent while it works
    assert result["method"] == "robust" and result["used"] == 8
    assert len(result["registration"]) == 8 and result["excluded"] == []
    assert result["seconds"] > 0 and result["peak_memory_mb"] > 0
    img = tifffile.imread(out)
    assert img.dtype == np.uint16 and img.shape == (256, 256)
    assert out.with_suffix(".png").is_file()


def test_mfsr_float_and_baseline(tmp_path, burst2, capsys):
    b = _burst(tmp_path, burst2)
    out = tmp_path / "sr.tif"
    assert (
        main(["mfsr", str(b), "--scale", "2", "--method", "baseline", "--float", "--out", str(out)])
        == 0
    )
    assert tifffile.imread(out).dtype == np.float32
    assert "baseline" in capsys.readouterr().out


def test_compare_with_reference(tmp_path, burst2, hr, capsys):
    b = _burst(tmp_path, burst2)
    ref = tmp_path / "ref.tif"
    tifffile.imwrite(ref, np.rint(hr * 4000).astype(np.uint16))
    assert (
        main(
            [
                "mfsr",
                "compare",
                str(b),
                "--scale",
                "2",
                "--reference",
                str(ref),
                "--out",
                str(tmp_path / "cmp"),
                "--json",
            ]
        )
        == 0
    )
    captured = capsys.readouterr()
    r = json.loads(captured.out)
    assert captured.err.splitlines() == [
        f"mfsr compare: {i}/3 {m} x2" for i, m in enumerate(("bicubic", "baseline", "robust"), 1)
    ]
    m = r["methods"]
    assert m["robust"]["psnr_db"] > m["baseline"]["psnr_db"] > 0
    with Image.open(tmp_path / "cmp" / "crops.png") as im:
        crops = np.asarray(im.convert("RGB"))
    assert crops.shape == (256 + 20, 3 * 256 + 2 * 4, 3)
    for i in range(3):  # a label above each panel: text on a white strip
        strip = crops[:20, i * 260 : i * 260 + 256]
        assert (strip == 255).all(axis=2).mean() > 0.5 and (strip < 100).any(), i
    assert crop_label("robust", m["robust"]).startswith("robust ") and " dB, SSIM " in (
        crop_label("robust", m["robust"])
    )
    assert crop_label("bicubic", {}) == "bicubic"


def test_bad_burst_dir_is_exit_1(tmp_path, capsys):
    assert main(["mfsr", str(tmp_path), "--scale", "2", "--out", str(tmp_path / "x.tif")]) == 1
    assert "no manifest.json" in capsys.readouterr().err


def test_burst_plan_json(tmp_path, capsys):
    out = tmp_path / "plan.json"
    assert (
        main(
            [
                "burst",
                "plan",
                "--scale",
                "2",
                "--focal-length-mm",
                "35",
                "--pixel-pitch-um",
                "2.2",
                "--distance-mm",
                "500",
                "--frames",
                "8",
                "--out",
                str(out),
                "--json",
            ]
        )
        == 0
    )
    r = json.loads(capsys.readouterr().out)
    assert r["frames"] == 8 and len(r["positions_mm"]) == 8
    assert json.loads(out.read_text())["scale"] == 2


@pytest.mark.skipif(
    importlib.util.find_spec("distributed") is None, reason="dask[distributed] not installed"
)
def test_several_bursts_in_parallel(tmp_path, burst2, capsys):
    frames, _ = burst2
    dirs = []
    for name, sl in (("a", slice(0, 6)), ("b", slice(6, 12))):
        dn = [np.clip(np.rint(f * 4000), 0, 65535).astype(np.uint16) for f in frames[sl]]
        dirs.append(str(write_burst(tmp_path / name, dn)))
    out = tmp_path / "out"
    environ = dict(os.environ)
    assert main(["mfsr", *dirs, "--scale", "2", "--out", str(out), "--json"]) == 0
    stdout, stderr = capsys.readouterr()
    assert len(stdout.splitlines()) == 1  # --json: the one object, progress elsewhere
    r = json.loads(stdout)
    assert [b["out"] for b in r["bursts"]] == [str(out / "a.tif"), str(out / "b.tif")]
    assert [b["used"] for b in r["bursts"]] == [6, 6]
    # progress on stderr as each burst finishes: plain lines (not a terminal), rate, time left
    lines = stderr.splitlines()
    assert [line.split()[1] for line in lines] == ["0/2", "1/2", "2/2"], stderr
    assert lines[-1].startswith("mfsr: 2/2 bursts fused (last: ") and "left)" in lines[-1]
    assert "\r" not in stderr and "━" not in stderr
    assert (out / "a.tif").is_file() and (out / "b.tif").is_file()
    # The local cluster's single-threaded BLAS settings do not stay in this process.
    assert dict(os.environ) == environ


def test_compare_json_is_strict_when_a_method_equals_the_reference(tmp_path, burst2):
    """bicubic against its own output: an infinite PSNR, written as null and named."""
    from elphel_host.burst.io import read_burst
    from elphel_host.mfsr.fuse import fuse_burst

    b = _burst(tmp_path, burst2)
    ref = tmp_path / "ref.tif"
    tifffile.imwrite(ref, fuse_burst(read_burst(b), scale=2, method="bicubic").image)
    out = tmp_path / "cmp"
    args = ["mfsr", "compare", str(b), "--scale", "2", "--reference", str(ref), "--float"]
    assert main([*args, "--out", str(out)]) == 0

    def refuse(name):
        raise AssertionError(f"{name} in compare.json")

    doc = json.loads((out / "compare.json").read_text(), parse_constant=refuse)
    assert doc["methods"]["bicubic"]["psnr_db"] is None
    assert doc["non_finite"] == {"methods.bicubic.psnr_db": "Infinity"}
    assert doc["methods"]["robust"]["psnr_db"] > 0
