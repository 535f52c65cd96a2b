"""The typed camera client against a scripted daemon (httpx mock transport)."""

import io
import json

import httpx
import numpy as np
import pytest
import tifffile

from elphel_host.camera import CameraClient, CameraHTTPError, CameraUnauthorizedError, CapturedBurst
from elphel_host.camera.events import SSEParser
from elphel_host.errors import CameraClientError


class FakeDaemon:
    """Two ports of parameters; PATCHes on ``fail_port`` are refused with 422."""

    def __init__(self, fail_port: int | None = None) -> None:
        self.params = {0: {"EXPOS": 10000, "GAINR": 0x10000}, 1: {"EXPOS": 10000, "GAINR": 0x10000}}
        self.fail_port = fail_port
        self.log: list[tuple[str, int, dict]] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        if request.headers.get("authorization") != "Bearer t":
            return httpx.Response(401, json={"detail": "token", "error": "unauthorized"})
        port = int(request.url.path.split("/")[4])
        if request.method == "GET":
            return httpx.Response(200, json=self.params[port])
        changes = json.loads(request.content)
        self.log.append((request.method, port, changes))
        if port == self.fail_port:
            body = {"detail": "no", "error": "parameter_range", "parameter": "EXPOS"}
            return httpx.Response(422, json={**body, "value": changes["EXPOS"], "allowed": "1..9"})
        self.params[port].update(changes)
        return httpx.Response(200, json={"frame": 7, "params": self.params[port]})


def camera(daemon: FakeDaemon, token: str = "t") -> CameraClient:
    return CameraClient("http://cam", token, transport=httpx.MockTransport(daemon))


def test_staged_restores_the_previous_values_on_exit():
    daemon = FakeDaemon()
    with camera(daemon) as cam:
        with cam.staged({"EXPOS": 500}) as applied:
            assert applied[0].frame == 7 and daemon.params[0]["EXPOS"] == 500
        assert daemon.params[0] == {"EXPOS": 10000, "GAINR": 0x10000}
        with pytest.raises(RuntimeError), cam.staged({"GAINR": 0x20000}):
            raise RuntimeError("the block failed")
        assert daemon.params[0]["GAINR"] == 0x10000


def test_staged_rolls_back_the_ports_done_when_one_fails_halfway():
    daemon = FakeDaemon(fail_port=1)
    with camera(daemon) as cam:
        with (
            pytest.raises(CameraHTTPError) as err,
            cam.staged({0: {"EXPOS": 500}, 1: {"EXPOS": 99}}),
        ):
            pytest.fail("the block must not run")
        assert err.value.status == 422 and err.value.parameter == "EXPOS"
        assert err.value.value == 99 and err.value.allowed == "1..9"
    assert daemon.params[0]["EXPOS"] == 10000
    assert [entry[1] for entry in daemon.log] == [0, 1, 0]


def test_missing_token_is_an_auth_error():
    with camera(FakeDaemon(), token="") as cam, pytest.raises(CameraUnauthorizedError):
        cam.set_params({"EXPOS": 5})


def test_sse_parser_reads_events_ids_and_skips_comments():
    parser = SSEParser()
    lines = [
        "retry: 2000",
        "",
        ": keepalive",
        "",
        "id: 3",
        "event: frame",
        'data: {"frame": 9}',
        "",
    ]
    events = [e for e in map(parser.feed, lines) if e is not None]
    assert len(events) == 1
    assert (events[0].type, events[0].id, events[0].data) == ("frame", 3, {"frame": 9})


def _composites(starts: list[int], *, period: int = 1000, strips: int = 4) -> CapturedBurst:
    meta = [
        {
            "frame": 10 + k,
            "timestamp_ns": t,
            "PF_HEIGHT": 2,
            "pf_strips": strips,
            "pf_strip_period_ns": period,
        }
        for k, t in enumerate(starts)
    ]
    images = np.arange(len(starts) * 2 * strips * 3, dtype=np.uint16).reshape(len(starts), -1, 3)
    return CapturedBurst(tiff=b"", images=images, metadata=meta)


def test_photofinish_joins_contiguous_composites_with_row_times():
    joined = _composites([5000, 9000, 13000]).photofinish()
    assert joined.image.shape == (24, 3) and joined.frames == [10, 11, 12]
    assert joined.image[8, 0] == 24  # first row of the second composite
    assert joined.row_times_ns[:4].tolist() == [5000, 5000, 6000, 6000]
    assert np.all(np.diff(joined.row_times_ns[::2]) == 1000)


def test_photofinish_refuses_gaps_and_plain_frames():
    with pytest.raises(CameraClientError, match=r"not contiguous: \+1\.0 strips"):
        _composites([5000, 10000]).photofinish()
    plain = CapturedBurst(
        tiff=b"", images=np.zeros((2, 4, 4), np.uint16), metadata=[{"frame": 1}] * 2
    )
    with pytest.raises(CameraClientError, match="PF_HEIGHT"):
        plain.photofinish()


class SlowFormingDaemon:
    """A daemon whose captures time out ``slow`` times; its frames move on unless ``stuck``."""

    def __init__(self, slow: int, *, stuck: bool = False) -> None:
        self.slow, self.stuck = slow, stuck
        self.frame = 100
        self.captures = 0

    def __call__(self, request: httpx.Request) -> httpx.Response:
        if request.url.path.endswith("/frame"):
            if not self.stuck:
                self.frame += 3
            return httpx.Response(200, json={"port": 0, "frame": self.frame, "timestamp_ns": 0})
        self.captures += 1
        if self.captures <= self.slow:
            raise httpx.ReadTimeout("timed out", request=request)
        buffer = io.BytesIO()
        metadata = json.dumps({"frame": self.frame, "port": 0})
        tifffile.imwrite(buffer, np.zeros((4, 6), np.uint16), description=metadata, metadata=None)
        body = buffer.getvalue()
        return httpx.Response(200, content=body, headers={"X-Frame-Number": str(self.frame)})


def test_a_capture_waits_on_while_the_daemons_frames_move_on():
    daemon = SlowFormingDaemon(slow=3)
    with camera(daemon) as cam:
        got = cam.capture(0)
    assert daemon.captures == 4 and got.image.shape == (4, 6)


@pytest.mark.parametrize(("slow", "stuck"), [(2, True), (100, False)])
def test_a_capture_gives_up_when_frames_stand_still_or_after_its_tries(slow, stuck):
    from elphel_host.camera.client import CAPTURE_TRIES

    daemon = SlowFormingDaemon(slow=slow, stuck=stuck)
    with camera(daemon) as cam, pytest.raises(CameraClientError, match="timed out"):
        cam.capture(0)
    assert daemon.captures == (1 if stuck else CAPTURE_TRIES)


def test_a_burst_waits_on_for_its_first_bytes_while_the_frames_move_on():
    daemon = SlowFormingDaemon(slow=2)
    with camera(daemon) as cam:
        got = cam.burst(1)
    assert daemon.captures == 3 and got.complete and len(got.metadata) == 1
