"""`elphel camera ...` builds its camera through connect(): either URL, one-line errors."""

import socket

import pytest

from elphel_host.cli import main


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("command", [["info"], ["get", "EXPOS"], ["capture"]])
def test_an_unreachable_stock_camera_is_one_line_naming_its_url(command, capsys, tmp_path):
    port = _free_port()  # nothing listens there
    url = f"nc393://127.0.0.1:{port}?imgsrv={port}"
    code = main(
        [
            "camera",
            *command,
            "--camera",
            url,
            *(["--out", str(tmp_path / "f.tif")] if command == ["capture"] else []),
        ]
    )
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1
    assert err.startswith(f"elphel: cannot reach the camera at http://127.0.0.1:{port}/")


def test_a_url_of_no_backend_is_refused_in_one_line(capsys):
    assert main(["camera", "info", "--camera", "ftp://cam.lab:8000"]) == 1
    err = capsys.readouterr().err
    assert err == (
        "elphel: camera url 'ftp://cam.lab:8000': scheme 'ftp' names no camera backend; allowed: "
        "http://HOST:PORT or https://HOST:PORT (elphel-camd), "
        "nc393://HOST[:HTTP_PORT][?imgsrv=BASE]\n"
    )
