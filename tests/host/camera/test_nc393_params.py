"""The stock NC393 backend's parsedit.php traffic, request by request (transcript tests)."""

import httpx
import pytest

from elphel_host.camera.nc393 import parsedit
from elphel_host.errors import (
    CameraClientError,
    CameraParameterError,
    ReadBackError,
    UnsupportedError,
)
from tests.host.camera.stock_transcript import (
    MT9P006_STATE,
    STATE_NAMES,
    WEB,
    Transcript,
    client,
    sensor_read,
    state_read,
    xml,
)


def test_info_names_each_ports_sensor_from_its_code():
    steps = [
        (f"{WEB}0&SENSOR&FRAME", xml({"SENSOR": 0x34, "FRAME": 7})),
        (f"{WEB}1&SENSOR&FRAME", xml({"SENSOR": 0, "FRAME": 0})),
        (f"{WEB}2&SENSOR&FRAME", xml({"SENSOR": 0x48, "FRAME": 9})),
        (f"{WEB}3&SENSOR&FRAME", xml({"SENSOR": 0x38, "FRAME": 8})),
    ]
    t = Transcript(steps)
    with client(t) as cam:
        info = cam.info()
    t.done()
    assert info["board"] == "nc393" and "trigger" in info["capabilities"]
    assert info["version"] is None  # the stock firmware reports none (not "unknown")
    ports = info["ports"]
    assert ports[0]["sensor"] == {
        "model": "MT9P006",
        "sensor_code": 0x34,
        "bayer": "GRBG",
        "bits": 12,  # the scale its frames are decoded to, as elphel-camd reports it
        "supported": True,
    }
    assert ports[0]["frame"] == 7
    assert ports[1] == {"port": 1, "sensor": None}
    assert ports[2]["sensor"]["model"] == "Boson640" and not ports[2]["sensor"]["supported"]
    assert ports[3]["sensor"]["model"] == "MT9F002"


def test_params_reads_the_models_names_in_one_request():
    extra = {"FP1000S": 14077, "COLOR": 5, "BITS": 8, "QUALITY": 100}
    steps = [
        sensor_read(),
        (
            f"{WEB}0&{STATE_NAMES}&SENSOR&FRAME&FP1000S&COLOR&BITS&QUALITY",
            xml({**MT9P006_STATE, "SENSOR": 0x34, "FRAME": 50, **extra}),
        ),
        (f"{WEB}0&EXPOS&FRAME", xml({"EXPOS": 10003, "FRAME": 51})),
    ]
    t = Transcript(steps)
    with client(t) as cam:
        assert cam.params(0) == {**MT9P006_STATE, "SENSOR": 0x34, "FRAME": 50, **extra}
        assert cam.params(0, names=("EXPOS",)) == {"EXPOS": 10003}
    t.done()


def _write(query: str, frame: int) -> tuple[str, httpx.Response]:
    return (f"{WEB}0&{query}&FRAME", xml({"EXPOS": 10003, "FRAME": frame}))


def test_set_params_writes_once_ahead_and_confirms_at_the_reported_frame():
    steps = [
        sensor_read(),
        state_read(frame=100),
        _write("EXPOS=5000*4&GAINR=131072*4", 100),
        state_read(frame=103),  # not yet: the client polls on
        state_read(frame=104, EXPOS=4983, VEXPOS=137, GAINR=0x20000),
    ]
    t = Transcript(steps)
    with client(t) as cam:
        applied = cam.set_params({"EXPOS": 5000, "GAINR": 0x20000}, ahead=4)
    t.done()
    assert applied.frame == 104
    assert applied.params["EXPOS"] == 4983 and applied.params["GAINR"] == 0x20000


def test_set_params_without_a_frame_takes_the_earliest_the_latency_allows():
    steps = [
        sensor_read(),
        state_read(frame=10),
        _write("EXPOS=5000*3", 10),  # exposure: 2 frames of latency in free-run, + 1
        state_read(frame=13, EXPOS=4983, VEXPOS=137),
    ]
    t = Transcript(steps)
    with client(t) as cam:
        assert cam.set_params({"EXPOS": 5000}).frame == 13
    t.done()


def test_absolute_frame_is_k_frames_from_now_and_a_missed_one_is_an_error():
    steps = [sensor_read(), state_read(frame=100), _write("EXPOS=5000*5", 100)]
    steps.append(state_read(frame=105, EXPOS=4983, VEXPOS=137))
    t = Transcript(steps)
    with client(t) as cam:
        assert cam.set_params({"EXPOS": 5000}, frame=105).frame == 105
    t.done()
    t = Transcript([sensor_read(), state_read(frame=100), _write("EXPOS=5000*5", 101)])
    with (
        client(t) as cam,
        pytest.raises(CameraClientError, match=r"frame 105 missed.*from frame 106"),
    ):
        cam.set_params({"EXPOS": 5000}, frame=105)
    t.done()


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"WOI_WIDTH": 3000}, r"WOI_WIDTH=3000 is out of range; allowed: 2\.\.2592 \(even\)"),
        ({"NOPE": 1}, "NOPE=1 is out of range; allowed: one of BIN_HOR, BIN_VERT, BITS, COLOR"),
        ({"FRAME": 5}, "FRAME=5 .*read-only"),
        ({"EXPOS": "5000"}, "an integer"),
        ({"COLOR": 3}, r"COLOR=3 .*allowed: 0 \(mono JPEG\), 2 \(JP46\), 5 \(JP4\) or 15"),
        ({"TRIG_PERIOD": 100_000}, "TRIG_PERIOD=100000 .*set on the master port 1"),
        ({"GTAB_R": 0x0A050400}, r"GTAB_R=168100864 .*gamma 0\.13\.\.2\.55"),
    ],
)
def test_bad_values_are_refused_before_anything_is_written(changes, match):
    url, answer = state_read(frame=100, TRIG_MASTER=1)
    stock = [n for n in changes if n in ("COLOR", "GTAB_R")]
    if stock:  # a stock-only parameter is read with the state
        url = url + "".join(f"&{n}" for n in stock)
        answer = xml({**MT9P006_STATE, "TRIG_MASTER": 1, "FRAME": 100})
    t = Transcript([sensor_read(), (url, answer)])
    with client(t) as cam, pytest.raises(CameraParameterError, match=match) as err:
        cam.set_params(changes)
    t.done()  # the state was read; no write was sent
    assert "\n" not in str(err.value) and err.value.parameter == next(iter(changes))


def test_ahead_outside_the_stock_window_is_refused_before_writing():
    t = Transcript([sensor_read(), state_read(frame=100)] * 1 + [state_read(frame=100)])
    with client(t) as cam:
        with pytest.raises(CameraParameterError, match=r"ahead=2 is too soon .*ahead 3\.\.6"):
            cam.set_params({"EXPOS": 5000}, ahead=2)
        with pytest.raises(UnsupportedError, match=r"at most 6 frames ahead .*maxahead"):
            cam.set_params({"EXPOS": 5000}, ahead=7)
    t.done()


def test_a_value_the_camera_did_not_take_is_a_read_back_error():
    steps = [
        sensor_read(),
        state_read(frame=100),
        _write("GAINR=131072*4", 100),
        state_read(frame=104),  # GAINR still 0x10000
    ]
    t = Transcript(steps)
    with client(t) as cam, pytest.raises(ReadBackError) as err:
        cam.set_params({"GAINR": 0x20000}, ahead=4)
    t.done()
    assert (err.value.parameter, err.value.asked, err.value.found) == ("GAINR", 0x20000, 0x10000)
    assert "GAINR=131072 asked, GAINR=65536 in effect at frame 104" in str(err.value)


def test_exposure_read_back_allows_the_cameras_own_row_rounding():
    steps = [
        sensor_read(),
        state_read(frame=1),
        _write("EXPOS=5000*3", 1),
        state_read(frame=4, EXPOS=5010, VEXPOS=137),  # within one 36 us row of 4983
    ]
    t = Transcript(steps)
    with client(t) as cam:
        assert cam.set_params({"EXPOS": 5000}).params["EXPOS"] == 5010
    t.done()
    steps[-1] = state_read(frame=4, EXPOS=5100, VEXPOS=140)
    t = Transcript(steps)
    with client(t) as cam, pytest.raises(ReadBackError, match="EXPOS=5000 asked, EXPOS=5100"):
        cam.set_params({"EXPOS": 5000})


def test_a_port_without_a_sensor_is_one_line():
    t = Transcript([sensor_read(port=1, code=0)])
    with client(t) as cam, pytest.raises(CameraClientError) as err:
        cam.set_params({"EXPOS": 5000}, port=1)
    assert str(err.value) == "nc393://cam:80?imgsrv=2323: port 1 has no sensor (SENSOR 0)"


def test_an_unsupported_sensor_is_named():
    t = Transcript([sensor_read(code=0x48)])
    with client(t) as cam, pytest.raises(UnsupportedError, match=r"Boson640 \(SENSOR 0x48\)"):
        cam.params(0)


def test_lepton_refuses_exposure_as_its_driver_does():
    lepton = {k: MT9P006_STATE[k] for k in MT9P006_STATE if k not in ("EXPOS", "VEXPOS")}
    lepton = {k: v for k, v in lepton.items() if not k.startswith("GAIN")}
    lepton.update(WOI_WIDTH=160, WOI_HEIGHT=120)
    read = f"{WEB}0&{'&'.join(lepton)}&FRAME"
    t = Transcript([sensor_read(code=0x44), (read, xml({**lepton, "FRAME": 3}))])
    with client(t) as cam, pytest.raises(UnsupportedError, match=r"LEPTON35 .*EXPOS"):
        cam.set_params({"EXPOS": 5000})
    t.done()


def test_unreachable_host_and_parsedit_errors_are_one_line():
    t = Transcript([(f"{WEB}0&SENSOR", httpx.ConnectError("connection refused"))])
    with client(t) as cam, pytest.raises(CameraClientError) as err:
        cam.params(0)
    assert str(err.value) == (
        "cannot reach the camera at http://cam/parsedit.php?immediate&sensor_port=0&SENSOR: "
        "connection refused"
    )
    for answer, match in [
        (httpx.Response(500, text="PHP Fatal error: x\nmore"), "HTTP 500: 'PHP Fatal error: x'"),
        (httpx.Response(200, text="<html>oops</html>"), "answered <html>, not <parameters>"),
        (httpx.Response(200, text="Warning: no\n"), "not a parsedit.php XML answer"),
        (xml({"FRAME": 3}), "did not answer SENSOR"),
        (xml({"SENSOR": "x"}), "answered SENSOR='x', not an integer"),  # type: ignore[dict-item]
        (
            httpx.Response(
                200,
                text='<?xml version="1.0"?>\n<framepars><ERROR>"Wrong address==0, probably '
                "misspelled constant: 'SENSR'\"</ERROR></framepars>\n",
            ),
            "parsedit.php error: Wrong address==0, probably misspelled constant: 'SENSR'$",
        ),
    ]:
        t = Transcript([(f"{WEB}0&SENSOR", answer)])
        with client(t) as cam, pytest.raises(CameraClientError, match=match) as err:
            cam.params(0)
        assert "\n" not in str(err.value) and "http://cam/parsedit.php" in str(err.value)


def test_features_the_stock_camera_lacks_raise_unsupported_naming_them():
    t = Transcript([(f"{WEB}0&EXPOS&FRAME", xml({"EXPOS": 1, "FRAME": 9}))])
    with client(t) as cam:
        with pytest.raises(UnsupportedError, match="no event stream"):
            cam.events()
        with pytest.raises(UnsupportedError, match="raw sensor registers"):
            cam.register(0x09)
        with pytest.raises(UnsupportedError, match="raw sensor registers"):
            cam.set_register(0x09, 1)
        with pytest.raises(UnsupportedError, match=r"frame 5: .*keeps no history"):
            cam.params(0, frame=5, names=("EXPOS",))
        with pytest.raises(ValueError, match=r"sensor port 4; allowed: 0\.\.3"):
            cam.params(4)
    t.done()


def test_staged_restores_through_the_same_checked_writes():
    steps = [
        sensor_read(),
        state_read(frame=1),  # staged reads the previous values
        state_read(frame=1),
        _write("GAINR=131072*2", 1),
        state_read(frame=3, GAINR=0x20000),
        state_read(frame=5, GAINR=0x20000),  # restore
        _write("GAINR=65536*2", 5),
        state_read(frame=7),
    ]
    steps[1] = (
        f"{WEB}0&{STATE_NAMES}&SENSOR&FRAME&FP1000S&COLOR&BITS&QUALITY",
        xml({**MT9P006_STATE, "SENSOR": 0x34, "FRAME": 1}),
    )
    t = Transcript(steps)
    with client(t) as cam, cam.staged({"GAINR": 0x20000}) as applied:
        assert applied[0].frame == 3
    t.done()


def test_write_query_orders_value_ahead_and_port_mask():
    query = parsedit.write_query(0, {"TRIG": 4, "TRIG_PERIOD": 50_000}, ahead=4, mask=0xF)
    assert query == "immediate&sensor_port=0&TRIG=4*4!f&TRIG_PERIOD=50000*4!f&FRAME"
    assert parsedit.read_query(2, ["SENSOR"]) == "immediate&sensor_port=2&SENSOR"


def test_one_masked_request_changes_several_ports_each_confirmed_at_its_frame():
    steps = [
        sensor_read(0),
        state_read(0, frame=100),
        sensor_read(2),
        state_read(2, frame=90),  # port 2 counts its own frames
        (f"{WEB}0&TRIG=4*3!5&FRAME", xml({"TRIG": 0, "FRAME": 101})),  # one frame passed
        state_read(0, frame=104, TRIG=4),
        state_read(2, frame=94, TRIG=4),
    ]
    t = Transcript(steps)
    with client(t) as cam:
        applied = cam.set_params_ports({"TRIG": 4}, (2, 0))
    t.done()
    assert {p: a.frame for p, a in applied.items()} == {0: 104, 2: 94}
    assert applied[2].params["TRIG"] == 4


def test_a_masked_change_one_port_refuses_writes_nothing():
    steps = [sensor_read(0), state_read(0, WOI_WIDTH=640), sensor_read(1), state_read(1)]
    t = Transcript(steps)
    with (
        client(t) as cam,
        pytest.raises(CameraParameterError, match=r"port 1: WOI_LEFT=1000 .*0\.\.0"),
    ):
        cam.set_params_ports({"WOI_LEFT": 1000}, [0, 1])
    t.done()
    with client(Transcript([])) as cam, pytest.raises(ValueError, match="sensor port 5"):
        cam.set_params_ports({"TRIG": 4}, [0, 5])
