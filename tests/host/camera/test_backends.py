"""A camera URL picks the backend: `connect` and the nc393:// URL form."""

import httpx
import pytest

from elphel_host.camera import CameraClient, connect
from elphel_host.camera.nc393.address import NC393Address, parse_nc393_url
from elphel_host.camera.nc393.client import NC393Client


def test_http_urls_are_elphel_camd():
    with connect("http://127.0.0.1:8000", "tok") as cam:
        assert isinstance(cam, CameraClient) and cam.url == "http://127.0.0.1:8000"
    with connect("https://cam.lab:8443/", None, timeout_s=5.0) as cam:
        assert isinstance(cam, CameraClient) and cam.timeout_s == 5.0


@pytest.mark.parametrize(
    ("url", "address"),
    [
        ("nc393://192.168.0.9", NC393Address("192.168.0.9", 80, 2323)),
        ("nc393://cam:8080", NC393Address("cam", 8080, 2323)),
        ("nc393://127.0.0.1:41234?imgsrv=41240", NC393Address("127.0.0.1", 41234, 41240)),
        ("nc393://cam/?imgsrv=3000", NC393Address("cam", 80, 3000)),
        ("nc393://[::1]:81", NC393Address("::1", 81, 2323)),
    ],
)
def test_nc393_urls_name_the_web_server_and_the_imgsrv_base(url, address):
    assert parse_nc393_url(url) == address


def test_nc393_services_are_where_the_url_says():
    seen: list[str] = []

    def answer(request: httpx.Request) -> httpx.Response:
        seen.append(str(request.url))
        if request.url.path == "/frame":
            return httpx.Response(200, text="17\n")
        return httpx.Response(200, text="<parameters><SENSOR>0</SENSOR></parameters>")

    url = "nc393://10.0.0.5:8080?imgsrv=3000"
    with connect(url, "ignored-token", transport=httpx.MockTransport(answer)) as cam:
        assert isinstance(cam, NC393Client) and cam.url == "nc393://10.0.0.5:8080?imgsrv=3000"
        cam.info()
        assert "authorization" not in {k.lower() for k in cam._web.headers}
    assert seen[0] == "http://10.0.0.5:8080/parsedit.php?immediate&sensor_port=0&SENSOR&FRAME"
    assert parse_nc393_url(url).imgsrv_url(3) == "http://10.0.0.5:3003"
    assert NC393Address("::1").imgsrv_url(0) == "http://[::1]:2323"


@pytest.mark.parametrize(
    ("url", "why"),
    [
        ("ftp://cam", "scheme 'ftp' names no camera backend"),
        ("cam:camd", "scheme 'cam' names no camera backend"),
        ("/dev/ttyUSB0", "scheme 'none' names no camera backend"),
        ("http://", "no host"),
        ("nc393://", "no host"),
        ("nc393://cam:99999", "the port is not a number in 1..65535"),
        ("nc393://cam:0", "port 0 is outside 1..65535"),
        ("nc393://cam?imgsrv=65534", "imgsrv=65534: its ports 65534..65537 must lie in 1..65535"),
        ("nc393://cam?imgsrv=abc", "imgsrv='abc' is not one port number"),
        ("nc393://cam?imgsrv=1&imgsrv=2", "imgsrv='1,2' is not one port number"),
        ("nc393://cam?port=2", "unknown query field"),
        ("nc393://cam/parsedit.php", "only a host, a port and"),
        ("nc393://root:pass@cam", "only a host, a port and"),
    ],
)
def test_bad_urls_are_one_line_naming_the_url_and_the_allowed_forms(url, why):
    with pytest.raises(ValueError) as err:
        connect(url)
    text = str(err.value)
    assert text.startswith(f"camera url {url!r}: {why}") and "\n" not in text
    assert text.endswith("nc393://HOST[:HTTP_PORT][?imgsrv=BASE]")


@pytest.mark.parametrize(
    ("given", "base"),
    [
        ("cam:8000", "http://cam:8000"),
        ("10.0.0.5:8000/", "http://10.0.0.5:8000"),
        ("http://cam:8000/api/v1", "http://cam:8000"),
        ("https://cam/api/v1/", "https://cam"),
    ],
)
def test_other_spellings_of_a_daemon_url_are_taken(given, base):
    with connect(given) as cam:
        assert isinstance(cam, CameraClient) and cam.url == base
