"""`elphel tp QUAD_DIR... --out-dir DIR`: many quads on a local Dask cluster.

The DSIs must be bit for bit those of the single-quad command, a broken quad must be
reported without losing the others, and a second run must skip what is done.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from elphel_host.cli import main
from elphel_host.errors import InputFormatError
from elphel_host.tp import dsi
from elphel_host.tp.sequence import find_quads, plan_jobs
from elphel_sim import quad as simquad


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three small quads (different noise seeds) in one directory."""
    root = tmp_path_factory.mktemp("seq")
    rig = simquad.QuadRig(width=160, height=96)
    for i in range(3):
        simquad.simulate_quad_dir(root / f"q{i}", rig, seed=10 + i)
    return root


def single_dsi(quad: Path, out: Path) -> dict[str, np.ndarray]:
    assert main(["tp", str(quad), "--out", str(out)]) == 0
    return dsi.read_dsi(out)[0]


def test_local_cluster_matches_single_runs_and_resumes(
    sequence: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    quads = tmp_path / "quads"
    shutil.copytree(sequence, quads)
    broken = quads / "q1b"
    shutil.copytree(quads / "q1", broken)
    (broken / "cam2.tif").write_bytes(b"not a tiff")
    out = tmp_path / "out"
    rc = main(["tp", str(quads), "--out-dir", str(out), "--workers", "2", "--json"])
    captured = capsys.readouterr()
    assert rc == 1  # one quad failed
    got = json.loads(captured.out)
    status = {Path(r["quad"]).name: r["status"] for r in got["quads"]}
    assert status == {"q0": "done", "q1": "done", "q1b": "failed", "q2": "done"}
    failed = next(r for r in got["quads"] if r["status"] == "failed")
    assert "cam2.tif" in failed["error"]
    assert "failed: " in captured.err and "4/4 quads" in captured.err
    assert sorted(p.name for p in out.iterdir()) == ["q0.tif", "q1.tif", "q2.tif"]
    for name in ("q0", "q1", "q2"):
        want = single_dsi(quads / name, tmp_path / f"single_{name}.tif")
        layers = dsi.read_dsi(out / f"{name}.tif")[0]
        assert list(layers) == list(want)
        for k in want:
            assert np.array_equal(layers[k], want[k], equal_nan=True), (name, k)
    # a re-run computes only what is missing: the repaired quad
    shutil.copy(quads / "q1" / "cam2.tif", broken / "cam2.tif")
    before = {n: (out / f"{n}.tif").stat().st_mtime_ns for n in ("q0", "q1", "q2")}
    capsys.readouterr()
    rc = main(["tp", str(quads), "--out-dir", str(out), "--workers", "1", "--json"])
    captured = capsys.readouterr()
    again = json.loads(captured.out)
    assert rc == 0
    # the rate counts the computed quad only: none while skipping, then about one quad's
    lines = captured.err.splitlines()
    assert [line for line in lines if "/s" in line] == lines[-1:], lines
    assert float(re.search(r"\(([\d.]+)/s", lines[-1]).group(1)) < 20, lines[-1]
    assert {Path(r["quad"]).name: r["status"] for r in again["quads"]} == {
        "q0": "skipped",
        "q1": "skipped",
        "q1b": "done",
        "q2": "skipped",
    }
    assert {n: (out / f"{n}.tif").stat().st_mtime_ns for n in before} == before
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary files left
    # q1b is a copy of q1: the same DSI
    a, b = dsi.read_dsi(out / "q1.tif")[0], dsi.read_dsi(out / "q1b.tif")[0]
    assert all(np.array_equal(a[k], b[k], equal_nan=True) for k in a)


def test_quad_lists_and_names(sequence: Path, tmp_path: Path) -> None:
    assert [p.name for p in find_quads([sequence])] == ["q0", "q1", "q2"]
    assert [p.name for p in find_quads([sequence / "q2", sequence / "q0"])] == ["q2", "q0"]
    with pytest.raises(InputFormatError, match=r"no quad\.json"):
        find_quads([tmp_path])
    with pytest.raises(InputFormatError, match="not a directory"):
        find_quads([tmp_path / "missing"])
    other = tmp_path / "x" / "q0"
    shutil.copytree(sequence / "q0", other)
    with pytest.raises(InputFormatError, match="share the name 'q0'"):
        plan_jobs([sequence / "q0", other], tmp_path / "out")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--out", "x.tif", "--out-dir", "d"], "--out and --out-dir"),
        (["--out-dir", "d", "--texture", "t.tif"], "--texture: only with one QUAD_DIR"),
        (["--out-dir", "d", "--workers", "0"], "--workers=0"),
        (["--out-dir", "d", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers"),
        (["--out", "x.tif", "--scheduler", "tcp://127.0.0.1:1"], "only with --out-dir"),
        ([], "--out DSI.tif is required"),
    ],
)
def test_usage_errors(
    sequence: Path, argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as e:
        main(["tp", str(sequence / "q0"), *argv])
    assert e.value.code == 2
    assert message in capsys.readouterr().err


def test_several_quads_need_out_dir(sequence: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["tp", str(sequence / "q0"), str(sequence / "q1"), "--out", "x.tif"])
    assert "give --out-dir DIR" in capsys.readouterr().err
