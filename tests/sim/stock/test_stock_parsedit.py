"""parsedit.php of the simulated stock NC393: exact requests, exact answers, right frames."""

import io
import re

from PIL import Image

from elphel_sim.stock.firmware import StockFirmware


def values(answer: str) -> dict[str, int]:
    return {k: int(v) for k, v in re.findall(r"<(\w+)>(-?\d+)</\1>", answer)}


def us(exposure: int) -> int:
    """An exposure as the sensor takes it: whole rows, the nearest 100 us here."""
    return round(exposure, -2)


def test_read_transcript(web):
    r = web.get("/parsedit.php?immediate&sensor_port=0&SENSOR&WOI_WIDTH&WOI_HEIGHT&COLOR&QUALITY")
    assert r.status_code == 200
    assert r.headers["content-type"].startswith("text/xml")
    assert r.headers["access-control-allow-origin"] == "*"
    assert r.content == (
        b'<?xml version="1.0"?>\n<parameters>\n'
        b"  <SENSOR>52</SENSOR>\n  <WOI_WIDTH>256</WOI_WIDTH>\n  <WOI_HEIGHT>128</WOI_HEIGHT>\n"
        b"  <COLOR>5</COLOR>\n  <QUALITY>100</QUALITY>\n</parameters>\n"
    )


def test_sensor_code_per_port_on_the_mixed_scenario(web):
    codes = {}
    for port in range(4):
        r = web.get(f"/parsedit.php?immediate&sensor_port={port}&SENSOR&COLOR&BITS")
        codes[port] = values(r.text)
    assert codes == {
        0: {"SENSOR": 0x34, "COLOR": 5, "BITS": 8},
        1: {"SENSOR": 0x38, "COLOR": 5, "BITS": 8},
        2: {"SENSOR": 0x44, "COLOR": 15, "BITS": 16},  # the Lepton: raw 16-bit only
        3: {"SENSOR": 0, "COLOR": 0, "BITS": 0},  # no sensor: every parameter reads 0
    }


def test_a_write_answers_the_values_before_it(web, firmware):
    before = values(web.get("/parsedit.php?immediate&EXPOS&FRAME").text)
    answer = values(web.get("/parsedit.php?immediate&FRAME&EXPOS=7000").text)
    assert answer["EXPOS"] == before["EXPOS"] and us(answer["EXPOS"]) == 5000
    assert firmware.wait_frame(0, answer["FRAME"] + 3)
    assert us(values(web.get("/parsedit.php?immediate&EXPOS").text)["EXPOS"]) == 7000


def effect(fw: StockFirmware, port: int, frame: int, name: str) -> list[int]:
    """The value of a parameter at frame-1, frame, frame+1 (after they were taken)."""
    assert fw.wait_frame(port, frame + 2)
    return [fw.service.params(port, frame=f)[name] for f in (frame - 1, frame, frame + 1)]


def test_ahead_writes_take_effect_exactly_at_frame_plus_k(web, firmware):
    previous = 5000
    for k in (3, 5, 6):
        exposure = 1000 * k
        answer = values(web.get(f"/parsedit.php?immediate&FRAME&EXPOS={exposure}*{k}").text)
        target = answer["FRAME"] + k
        got = [us(v) for v in effect(firmware, 0, target, "EXPOS")]
        assert got == [previous, exposure, exposure], k
        previous = exposure
    # The frame at the target was exposed so (what imgsrv encodes it with).
    encoded, metadata = firmware.encoded(0, target)
    exif = Image.open(io.BytesIO(encoded.data)).getexif()
    assert exif[0x9211] == metadata["frame"] == target  # ImageNumber
    exposure_s = exif.get_ifd(0x8769)[0x829A]
    assert us(round(float(exposure_s) * 1e6)) == us(metadata["EXPOS"]) == 6000


def test_farther_than_six_frames_the_script_waits_then_writes(web, firmware):
    answer = values(web.get("/parsedit.php?immediate&FRAME&EXPOS=3000*9").text)
    assert firmware.frame(0) >= answer["FRAME"] + 5  # answered after waiting for F+5
    target = answer["FRAME"] + 9
    assert [us(v) for v in effect(firmware, 0, target, "EXPOS")] == [5000, 3000, 3000]


def test_chained_values_each_on_its_frame(web, firmware):
    answer = values(web.get("/parsedit.php?immediate&FRAME&EXPOS=6000*3:8000*5").text)
    f = answer["FRAME"]
    assert firmware.wait_frame(0, f + 7)
    got = [us(firmware.service.params(0, frame=f + k)["EXPOS"]) for k in range(2, 7)]
    assert got == [5000, 6000, 6000, 8000, 8000]


def test_a_mask_writes_several_ports(web, firmware):
    web.get("/parsedit.php?immediate&sensor_port=0&GAINR=0x20000*3!3")
    for port in (0, 1):
        assert firmware.wait_frame(port, firmware.frame(port) + 4)
    gains = [values(web.get(f"/parsedit.php?immediate&sensor_port={p}&GAINR").text) for p in (0, 1)]
    assert [g["GAINR"] for g in gains] == [0x20000, 0x20000]


def test_too_late_writes_take_effect_as_soon_as_possible(web, firmware):
    answer = values(web.get("/parsedit.php?immediate&FRAME&EXPOS=4500*0").text)
    f = answer["FRAME"]
    assert firmware.wait_frame(0, f + 4)
    assert us(firmware.service.params(0, frame=f + 3)["EXPOS"]) == 4500


def test_bad_values_are_dropped_silently_one_by_one(web, firmware):
    answer = values(web.get("/parsedit.php?immediate&FRAME&EXPOS=6500&WOI_WIDTH=99999").text)
    assert us(answer["EXPOS"]) == 5000
    web.get("/parsedit.php?immediate&EXPOS=abc&COLOR=7&QUALITY=0")  # 0, JP4DIFF, 0: refused
    assert firmware.wait_frame(0, answer["FRAME"] + 5)
    now = values(web.get("/parsedit.php?immediate&EXPOS&WOI_WIDTH&COLOR&QUALITY").text)
    assert {**now, "EXPOS": us(now["EXPOS"])} == {
        "EXPOS": 6500,
        "WOI_WIDTH": 256,
        "COLOR": 5,
        "QUALITY": 100,
    }


def test_unknown_name_answers_the_scripts_error_and_writes_nothing(web, firmware):
    r = web.get("/parsedit.php?immediate&EXPOS=9000&EXPOSURE=1")
    assert r.status_code == 200
    assert r.content == (
        b'<?xml version="1.0"?>\n<framepars><ERROR>"Wrong address==0, probably '
        b"misspelled constant: 'EXPOSURE'\"</ERROR></framepars>\n"
    )
    assert firmware.wait_frame(0, firmware.frame(0) + 4)
    assert us(values(web.get("/parsedit.php?immediate&EXPOS").text)["EXPOS"]) == 5000


def test_read_only_and_empty_ports_ignore_writes(web, firmware):
    web.get("/parsedit.php?immediate&FRAME=5&SENSOR=1")
    web.get("/parsedit.php?immediate&sensor_port=3&EXPOS=5000")
    web.get("/parsedit.php?immediate&sensor_port=2&COLOR=5")  # the Lepton stays raw
    assert firmware.wait_frame(0, firmware.frame(0) + 4)
    assert values(web.get("/parsedit.php?immediate&SENSOR").text) == {"SENSOR": 0x34}
    assert values(web.get("/parsedit.php?immediate&sensor_port=2&COLOR").text) == {"COLOR": 15}


def test_without_immediate_only_a_page_no_change(web):
    r = web.get("/parsedit.php?EXPOS=9000")
    assert r.headers["content-type"].startswith("text/html") and "immediate" in r.text
    assert us(values(web.get("/parsedit.php?immediate&EXPOS").text)["EXPOS"]) == 5000
