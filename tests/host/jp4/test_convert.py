"""`elphel jp4 convert`: recordings to TIFFs, quad and burst directories, bad files, resuming."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest
import tifffile

from elphel_host.burst.io import read_burst
from elphel_host.camera.frames import read_tiff_metadata
from elphel_host.camera.jp4 import decode_jp4
from elphel_host.cli import main
from elphel_host.recordings import conversion, convert
from elphel_host.recordings.frames import read_recording
from elphel_host.recordings.names import find_inputs, recorded_name
from elphel_host.tp.io import read_quad_dir
from elphel_sim.jp4 import encode_jp4

SEC = 1_700_000_000


def record(
    root: Path, instants: int, channels: tuple[int, ...] = (0, 1, 2, 3), prefix: str = ""
) -> list[Path]:
    """Frames as Elphel's recorder names them: <sec>_<usec>_<channel>.jp4 (imgsrv: a prefix)."""
    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(11)
    paths = []
    for t in range(instants):
        for ch in channels:
            mosaic = rng.integers(0, 4096, (32, 64)).astype(np.uint16)
            data = encode_jp4(mosaic, bits=12, frame=500 + t, port=ch, exposure_us=800,
                              timestamp_ns=(SEC + t) * 10**9 + 250_000_000, gamma=0.57)  # fmt: skip
            path = root / f"{prefix}{SEC + t}_250000_{ch}.jp4"
            path.write_bytes(data)
            paths.append(path)
    return paths


def test_recorder_names() -> None:
    name = recorded_name(Path("1700000000_000123_2.jp4"))
    assert name is not None and (name.seconds, name.microseconds, name.channel) == (SEC, 123, 2)
    assert name.timestamp_ns == SEC * 10**9 + 123_000 and name.instant == "1700000000_000123"
    assert recorded_name(Path("frame.jp4")) is None
    # imgsrv's own download name (curl -OJ ".../towp/wait/bimg")
    name = recorded_name(Path("elphelimg_39_835773_0.jp4"))
    assert name is not None and (name.seconds, name.microseconds, name.channel) == (39, 835773, 0)
    assert recorded_name(Path("otherprefix_39_835773_0.jp4")) is None


def test_find_inputs(tmp_path: Path) -> None:
    paths = record(tmp_path / "rec", 1, (0, 1))
    (tmp_path / "rec" / "notes.txt").write_text("not a frame")
    (tmp_path / "empty").mkdir()
    found = find_inputs([tmp_path / "rec", paths[0], tmp_path / "nowhere", tmp_path / "empty"])
    assert found.files == tuple(paths)
    assert [(p.name, why) for p, why in found.missing] == [
        ("nowhere", "no such file or directory"),
        ("empty", "no .jp4, .jp46, .jpg, .jpeg files in this directory"),
    ]


def test_files_are_the_decoded_frames_with_capture_metadata(tmp_path: Path) -> None:
    paths = record(tmp_path / "rec", 1, (0, 1))
    result = convert([tmp_path / "rec"], tmp_path / "out")
    assert not result.failed and len(result.converted) == 2
    for path in paths:
        image, meta = read_tiff_metadata(str(tmp_path / "out" / f"{path.stem}.tif"))
        want_image, want_meta = decode_jp4(path.read_bytes())
        assert np.array_equal(image, want_image) and image.dtype == np.uint16
        assert meta == {**want_meta, "recorded_file": path.name}
        assert meta["source"] == "jp4" and meta["timestamp_ns"] == SEC * 10**9 + 250_000_000


def test_bad_files_are_reported_and_skipped(tmp_path: Path) -> None:
    paths = record(tmp_path / "rec", 1, (0, 1))
    good = paths[0].read_bytes()
    (tmp_path / "rec" / "cut.jp4").write_bytes(good[: len(good) // 2])
    (tmp_path / "rec" / "text.jp4").write_bytes(b"hello")
    result = convert([tmp_path / "rec", tmp_path / "gone.jp4"], tmp_path / "out")
    assert sorted(c.source.name for c in result.converted) == sorted(p.name for p in paths)
    reasons = {f.source.name: f.reason for f in result.failed}
    assert reasons == {
        "gone.jp4": f"{tmp_path / 'gone.jp4'}: no such file or directory",
        "cut.jp4": f"{tmp_path / 'rec' / 'cut.jp4'}: truncated JPEG: no end-of-image marker "
        f"after the scan data ({len(good) // 2} bytes)",
        "text.jp4": f"{tmp_path / 'rec' / 'text.jp4'}: not a JPEG: starts with 68656c6c",
    }
    assert not (tmp_path / "out" / "cut.tif").exists()


def test_a_rerun_skips_complete_outputs_and_redoes_damaged_ones(tmp_path: Path) -> None:
    record(tmp_path / "rec", 1, (0, 1, 2))
    convert([tmp_path / "rec"], tmp_path / "out")
    damaged = tmp_path / "out" / f"{SEC}_250000_1.tif"
    damaged.write_bytes(damaged.read_bytes()[:-100])
    again = convert([tmp_path / "rec"], tmp_path / "out")
    skipped = {c.source.name: c.skipped for c in again.converted}
    assert skipped == {f"{SEC}_250000_0.jp4": True, f"{SEC}_250000_1.jp4": False,
                       f"{SEC}_250000_2.jp4": True}  # fmt: skip
    assert tifffile.imread(damaged).shape == (32, 64)


def test_an_interrupt_keeps_what_was_converted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    paths = record(tmp_path / "rec", 2, (0, 1, 2))
    interrupted = threading.Event()
    calls = []

    def read(path: Path) -> object:
        calls.append(path)
        if len(calls) == 3:  # the frame being converted when Ctrl-C comes
            assert interrupted.wait(10)
        return read_recording(path)

    def stop(done: int, total: int, name: str) -> None:
        if done == 2:
            interrupted.set()
            raise KeyboardInterrupt

    monkeypatch.setattr(conversion, "read_recording", read)
    with pytest.raises(KeyboardInterrupt):
        convert([tmp_path / "rec"], tmp_path / "out", workers=1, progress=stop)
    written = sorted((tmp_path / "out").iterdir())
    assert [p.stem for p in written] == [p.stem for p in calls] == [p.stem for p in paths[:3]]
    monkeypatch.undo()
    resumed = convert([tmp_path / "rec"], tmp_path / "out", workers=1)
    assert [c.skipped for c in resumed.converted] == [True] * 3 + [False] * 3
    assert not resumed.failed


def test_two_inputs_with_one_output_name(tmp_path: Path) -> None:
    a = record(tmp_path / "a", 1, (0,))[0]
    b = record(tmp_path / "b", 1, (0,))[0]
    result = convert([a, b], tmp_path / "out")
    assert [c.source for c in result.converted] == [a]
    assert (
        result.failed[0].reason == f"{b}: its output {tmp_path / 'out' / a.stem}.tif is also {a}'s"
    )


@pytest.mark.parametrize("prefix", ["", "elphelimg_"])
def test_quad_directories_for_the_tile_processor(tmp_path: Path, prefix: str) -> None:
    record(tmp_path / "rec", 2, prefix=prefix)
    result = convert([tmp_path / "rec"], tmp_path / "out", layout="quad")
    assert not result.failed
    assert [d.name for d in result.directories] == [f"{SEC}_250000", f"{SEC + 1}_250000"]
    quad = read_quad_dir(tmp_path / "out" / f"{SEC}_250000")
    assert quad.manifest.positions == ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5))
    assert quad.manifest.bayer == "GRBG" and quad.full_scale_dn == 65535
    cams = [cam.fields for cam in quad.manifest.cameras]
    assert [c["port"] for c in cams] == [0, 1, 2, 3]
    assert {c["frame"] for c in cams} == {500}
    assert quad.quad.images.shape == (4, 32, 64)
    again = convert([tmp_path / "rec"], tmp_path / "out", layout="quad")
    assert all(c.skipped for c in again.converted) and len(again.converted) == 8


def test_quad_sets_that_cannot_be_made(tmp_path: Path) -> None:
    paths = record(tmp_path / "rec", 1, (0, 1, 3))
    other = tmp_path / "rec" / "frame.jp4"
    other.write_bytes(paths[0].read_bytes())
    result = convert([tmp_path / "rec"], tmp_path / "out", layout="quad")
    assert not result.converted and not result.directories
    reasons = {f.source.name: f.reason.split(": ", 1)[1] for f in result.failed}
    assert reasons["frame.jp4"].startswith(
        "not named [elphelimg_]<seconds>_<microseconds>_<channel>"
    )
    assert reasons[paths[0].name] == (
        f"quad {SEC}_250000 has channels [0, 1, 3]; a quad set needs 0, 1, 2, 3"
    )


def test_a_bad_frame_fails_its_quad_set_only(tmp_path: Path) -> None:
    paths = record(tmp_path / "rec", 2)
    paths[5].write_bytes(b"\xff\xd8\xff")
    result = convert([tmp_path / "rec"], tmp_path / "out", layout="quad")
    assert [d.name for d in result.directories] == [f"{SEC}_250000"]
    reasons = {f.source.name: f.reason for f in result.failed}
    assert reasons[paths[5].name].endswith("truncated JPEG: ends at byte 3 before the scan data")
    assert reasons[paths[4].name].endswith(
        f"quad {SEC + 1}_250000 not written: {paths[5].name} failed"
    )


def test_burst_directories_for_mfsr(tmp_path: Path) -> None:
    paths = record(tmp_path / "rec", 3, (1,))
    paths[1].write_bytes(b"junk")
    result = convert([tmp_path / "rec"], tmp_path / "out", layout="burst")
    assert [d.name for d in result.directories] == ["channel1"]
    assert [f.source for f in result.failed] == [paths[1]]
    burst = read_burst(tmp_path / "out" / "channel1")
    assert burst.bayer == "GRBG" and burst.frames.shape == (2, 32, 64)
    assert [e.frame for e in burst.infos] == [500, 502]
    assert [e.timestamp_ns for e in burst.infos] == [
        SEC * 10**9 + 250_000_000, (SEC + 2) * 10**9 + 250_000_000]  # fmt: skip
    assert burst.infos[0].extra == {"recorded_file": paths[0].name}


def test_a_burst_resumes_from_its_frames(tmp_path: Path) -> None:
    record(tmp_path / "rec", 3, (0,))
    convert([tmp_path / "rec"], tmp_path / "out", layout="burst")
    (tmp_path / "out" / "channel0" / "manifest.json").unlink()  # as if interrupted
    again = convert([tmp_path / "rec"], tmp_path / "out", layout="burst")
    assert all(c.skipped for c in again.converted) and len(again.converted) == 3
    assert len(read_burst(tmp_path / "out" / "channel0").infos) == 3


def test_unknown_layout(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="layout='tiles'; allowed: files, quad, burst"):
        convert([], tmp_path, layout="tiles")


def test_cli_json_and_exit_codes(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    paths = record(tmp_path / "rec", 1, (0, 1))
    (tmp_path / "rec" / "bad.jp4").write_bytes(b"nope")
    code = main(["jp4", "convert", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--json"])
    out, err = capsys.readouterr()
    assert code == 1
    doc = json.loads(out)
    assert doc["layout"] == "files" and len(doc["converted"]) == len(paths)
    assert doc["failed"] == [
        {"file": str(tmp_path / "rec" / "bad.jp4"),
         "error": f"{tmp_path / 'rec' / 'bad.jp4'}: not a JPEG: starts with 6e6f7065"}
    ]  # fmt: skip
    assert f"elphel: {tmp_path / 'rec' / 'bad.jp4'}: not a JPEG" in err
    assert "converting 3/3" in err  # progress on stderr, never on stdout
    (tmp_path / "rec" / "bad.jp4").unlink()
    assert main(["jp4", "convert", str(tmp_path / "rec"), "--out", str(tmp_path / "o")]) == 0
    assert capsys.readouterr().out.startswith("0 converted, 2 already done, 0 failed")


def test_cli_usage_errors(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as info:
        main(["jp4", "convert", "x.jp4", "--out", "o", "--workers", "0"])
    assert info.value.code == 2
    assert "--workers: '0'; allowed: an integer >= 1" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(["jp4", "convert", "x.jp4", "--out", "o", "--quad", "--burst"])
    assert info.value.code == 2


def test_frames_that_do_not_fit_are_left_out(tmp_path: Path) -> None:
    paths = record(tmp_path / "rec", 3, (2,))
    mosaic = np.zeros((32, 64), np.uint16)
    paths[1].write_bytes(encode_jp4(mosaic, bits=12, frame=1, timestamp_ns=0, flips=(1, 0)))
    result = convert([tmp_path / "rec"], tmp_path / "out", layout="burst")
    assert [(f.source, f.reason) for f in result.failed] == [
        (paths[1], f"{paths[1]}: bayer RGGB, 64x32; the burst's first frame: bayer GRBG, 64x32")
    ]
    assert not (tmp_path / "out" / "channel2" / "frames" / f"{paths[1].stem}.tif").exists()
    assert len(read_burst(tmp_path / "out" / "channel2").infos) == 2


def test_a_quad_of_mixed_bayer_orders(tmp_path: Path) -> None:
    paths = record(tmp_path / "rec", 1)
    mosaic = np.zeros((32, 64), np.uint16)
    paths[3].write_bytes(encode_jp4(mosaic, bits=12, frame=1, timestamp_ns=0, flips=(0, 1)))
    result = convert([tmp_path / "rec"], tmp_path / "out", layout="quad")
    assert not result.converted and len(result.failed) == 4
    assert result.failed[0].reason.endswith(
        f"quad {SEC}_250000: the cameras differ in Bayer order ['BGGR', 'GRBG']"
    )
    assert not (tmp_path / "out" / f"{SEC}_250000").exists()
