"""A scripted stock NC393 for transcript tests: exact requests in order, canned answers.

Each step is (URL the client must send, answer); a request other than the next expected
one fails the test, and `Transcript.done` fails if any step is left unconsumed.
"""

from __future__ import annotations

from collections.abc import Mapping

import httpx

from elphel_host.camera.nc393.client import NC393Client

WEB = "http://cam/parsedit.php?immediate&sensor_port="

MT9P006_STATE = {
    "EXPOS": 10003,
    "FLIPH": 0,
    "FLIPV": 0,
    "FP1000SLIM": 0,
    "FPSFLAGS": 0,
    "GAINB": 0x10000,
    "GAING": 0x10000,
    "GAINGB": 0x10000,
    "GAINR": 0x10000,
    "PF_HEIGHT": 0,
    "TRIG": 0,
    "TRIG_DECIMATE": 0,
    "TRIG_DELAY": 0,
    "TRIG_MASTER": 0,
    "TRIG_PERIOD": 0,
    "VEXPOS": 275,
    "WOI_HEIGHT": 1944,
    "WOI_LEFT": 0,
    "WOI_TOP": 0,
    "WOI_WIDTH": 2592,
}
STATE_NAMES = "&".join(MT9P006_STATE)


def xml(values: Mapping[str, int]) -> httpx.Response:
    """parsedit.php's answer: ``<parameters>`` with one element per name, decimal."""
    body = "".join(f"  <{k}>{v}</{k}>\n" for k, v in values.items())
    text = f'<?xml version="1.0"?>\n<parameters>\n{body}</parameters>\n'
    return httpx.Response(200, text=text, headers={"Content-Type": "text/xml"})


def state_read(port: int = 0, frame: int = 100, **changed: int) -> tuple[str, httpx.Response]:
    """The step reading an MT9P006 port's whole state and FRAME."""
    return (f"{WEB}{port}&{STATE_NAMES}&FRAME", xml({**MT9P006_STATE, **changed, "FRAME": frame}))


def sensor_read(port: int = 0, code: int = 0x34) -> tuple[str, httpx.Response]:
    """The step reading a port's SENSOR code."""
    return (f"{WEB}{port}&SENSOR", xml({"SENSOR": code}))


class Transcript:
    """An httpx handler answering a fixed sequence of requests."""

    def __init__(self, steps: list[tuple[str, httpx.Response | Exception]]) -> None:
        self.steps = list(steps)
        self.seen: list[str] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        url = str(request.url)
        self.seen.append(url)
        assert self.steps, f"unexpected request {url} (transcript finished)"
        want, answer = self.steps.pop(0)
        assert url == want, f"request {url}\n  expected {want}"
        if isinstance(answer, Exception):
            raise answer
        return answer

    def done(self) -> None:
        assert not self.steps, f"requests not sent: {[s[0] for s in self.steps]}"


def client(transcript: Transcript, url: str = "nc393://cam", **options: object) -> NC393Client:
    return NC393Client(url, transport=httpx.MockTransport(transcript), **options)  # type: ignore[arg-type]
