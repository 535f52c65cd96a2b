"""`elphel tp capture` without a camera: geometry files, trigger settings, usage errors."""

import json
from pathlib import Path

import pytest

from elphel_host.cli import main
from elphel_host.errors import InputFormatError
from elphel_host.tp.layout import read_layout
from elphel_host.tp.trigger import trigger_changes, trigger_ticks


def test_a_quad_json_or_the_simulators_quad_answer_is_a_geometry_file(tmp_path: Path) -> None:
    quad_json = {
        "version": 1,
        "cameras": [
            {"file": f"cam{i}.tif", "position": [x, y]}
            for i, (x, y) in enumerate([(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)])
        ],
        "bayer": "GRBG",
    }
    (tmp_path / "a.json").write_text(json.dumps(quad_json))
    layout = read_layout(tmp_path / "a.json")
    assert layout.ports == (0, 1, 2, 3) and layout.positions[3] == (0.5, 0.5)
    assert layout.optics is None
    swapped = {
        "cameras": [{"port": p, "position": [0.1 * p, 0]} for p in (2, 0, 3, 1)],
        "optics": {"baseline_mm": 150.0},
    }
    (tmp_path / "b.json").write_text(json.dumps(swapped))
    layout = read_layout(tmp_path / "b.json")
    assert layout.ports == (2, 0, 3, 1) and layout.optics == {"baseline_mm": 150.0}


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ("not json", "not valid JSON"),
        ({"cameras": [{"position": [0, 0]}] * 3}, "must list 4 cameras"),
        ({"cameras": [{"position": [0, "a"]}] * 4}, r"cameras\[0\]\.position=\[0, 'a'\]"),
        ({"cameras": [{"port": -1, "position": [0, 0]}] * 4}, r"cameras\[0\]\.port=-1"),
        ({"cameras": [{"port": 1, "position": [0, 0]}] * 4}, "four different ports"),
        ({"cameras": [{"position": [0, 0]}] * 4, "optics": 3}, "optics=3"),
    ],
)
def test_bad_geometry_files_name_the_field(tmp_path: Path, doc: object, message: str) -> None:
    file = tmp_path / "g.json"
    file.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    with pytest.raises(InputFormatError, match=message):
        read_layout(file)


def test_trigger_period_in_ticks_and_its_limit() -> None:
    assert trigger_ticks(500) == 50_000_000
    with pytest.raises(ValueError, match=r"0\.001 ms; allowed: >= 0\.00256 ms"):
        trigger_ticks(0.001)


def test_the_common_trigger_is_staged_apart_from_the_ports() -> None:
    free = {"TRIG": 0, "TRIG_MASTER": 0, "TRIG_PERIOD": 0, "TRIG_DELAY": 0, "TRIG_DECIMATE": 0}
    before = {p: dict(free) for p in range(4)}
    before[3].update(TRIG=20, TRIG_DELAY=500, TRIG_MASTER=1)
    common, ports = trigger_changes(before, master=0, period=50_000_000)
    assert common == {0: {"TRIG_PERIOD": 50_000_000}}
    assert ports == {
        0: {"TRIG": 4},
        1: {"TRIG": 4},
        2: {"TRIG": 4},
        3: {"TRIG_MASTER": 0, "TRIG_DELAY": 0},  # snapshot with GRR stays
    }


def test_options_of_the_other_form_are_usage_errors(tmp_path: Path) -> None:
    out = str(tmp_path / "x")
    with pytest.raises(SystemExit) as e:
        main(["tp", "capture", "--camera", "http://h:1", "--out", out, "--refine", "2"])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        main(["tp", str(tmp_path), "--out", out, "--force"])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        main(["tp", "capture", "--out", out, "--camera", ""])
    assert e.value.code == 2
