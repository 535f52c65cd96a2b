"""`elphel-sim up --camera-port/--stage-port`: a bad port is a usage error, not a traceback."""

from __future__ import annotations

import socket

import pytest

from elphel_sim.cli import main


@pytest.mark.parametrize("flag", ["--camera-port", "--stage-port"])
@pytest.mark.parametrize("value", ["-1", "65536", "http"])
def test_bad_port_is_one_usage_line(
    flag: str, value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as info:
        main(["up", flag, value])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {flag}: '{value}'; allowed: 0 (a free port) to 65535" in err
    assert "Traceback" not in err


@pytest.mark.parametrize("flag", ["--camera-port", "--stage-port"])
def test_busy_port_is_named(flag: str, capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        assert main(["up", flag, str(port)]) == 1
    err = capsys.readouterr().err
    assert f"cannot listen on 127.0.0.1:{port}" in err and "Traceback" not in err
