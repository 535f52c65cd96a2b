"""What a newcomer meets in the first hour with `elphel camera`, against a simulated rig.

Each check is one item of the first-hour list: the parameter list, lower-case names,
*why* a value is refused, a wrong token, and a watch on a port that does not exist.
"""

from __future__ import annotations

import json
import time

import pytest

from elphel_host.cli import main


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_camera_commands_say_what_a_newcomer_needs(elphel_rig, capsys) -> None:
    cam = ["--camera", elphel_rig.camera_url, "--token", elphel_rig.token]

    code, out, _ = run(capsys, "camera", "params", *cam, "--json")
    assert code == 0
    rows = {r["name"]: r for r in json.loads(out)["params"]}
    assert rows["WOI_WIDTH"]["range"] == "2..2592 (even)"  # the MT9P006's, not 2..65535
    assert rows["WOI_WIDTH"]["unit"] == "pixels" and rows["WOI_WIDTH"]["value"] == 2592
    assert rows["EXPOS"]["unit"] == "us" and rows["EXPOS"]["description"] == "exposure time"
    assert rows["FRAME"]["read_only"] and rows["FRAME"]["range"] == "read-only"
    code, out, _ = run(capsys, "camera", "params", *cam)
    assert code == 0 and "WOI_WIDTH" in out and "2..2592 (even)" in out

    # Names in any case.
    code, out, _ = run(capsys, "camera", "set", "expos=5000", *cam, "--json")
    assert code == 0 and 4900 <= json.loads(out)["params"]["EXPOS"] <= 5100
    code, out, _ = run(capsys, "camera", "get", "expos", *cam, "--json")
    assert code == 0 and list(json.loads(out)) == ["EXPOS"]

    # Why a value is refused.
    code, _, err = run(capsys, "camera", "set", "WOI_WIDTH=641", *cam)
    assert code == 1 and "WOI_WIDTH=641 refused: must be even" in err
    code, _, err = run(capsys, "camera", "set", "WOI_WIDTH=4000", *cam)
    assert code == 1 and "WOI_WIDTH=4000 refused: out of range 2..2592" in err

    # A wrong token is called that; no token at all is asked for.
    wrong = ["--camera", elphel_rig.camera_url, "--token", "not-the-token"]
    code, _, err = run(capsys, "camera", "set", "EXPOS=5000", *wrong)
    assert code == 1 and err.startswith("elphel: wrong token")
    code, _, err = run(capsys, "camera", "set", "EXPOS=5000", "--camera", elphel_rig.camera_url)
    assert code == 1 and "needs its token" in err

    # A watch on a port the camera does not have fails at once instead of waiting.
    t0 = time.monotonic()
    code, _, err = run(capsys, "camera", "watch", "--sensor-port", "5", *cam)
    assert code == 1 and "port 5 does not exist; ports: 0" in err
    assert time.monotonic() - t0 < 5.0

    # `burst plan --camera` plans for the sensor the camera has (a Bayer MT9P006 here).
    optics = ["--scale", "2", "--focal-length-mm", "4.5", "--distance-mm", "1000"]
    code, out, _ = run(capsys, "burst", "plan", *optics, *cam, "--json")
    assert code == 0
    read = json.loads(out)
    assert read["sensor"] == {"model": "MT9P006", "pixel_pitch_um": 2.2, "bayer": "GRBG", "port": 0}
    code, out, _ = run(
        capsys, "burst", "plan", *optics, "--pixel-pitch-um", "2.2", "--bayer", "--json"
    )
    assert code == 0
    by_hand = json.loads(out)
    assert read["bayer"] is True and read["tilt_deg"] == by_hand["tilt_deg"]
    assert read["positions_mm"] == by_hand["positions_mm"]
    code, _, err = run(capsys, "burst", "plan", *optics, *cam, "--pixel-pitch-um", "1.4")
    assert code == 1 and "has 2.2 um pixels" in err
