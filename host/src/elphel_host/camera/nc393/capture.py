"""Frames of a stock NC393 through imgsrv: `StockFrames`, the capture half of `NC393Client`.

``capture`` takes the next frame (``/towp/wait/bimg``) or one by number, from the buffer
with imgsrv's ``prev`` moves and checked by its Exif frame number; ``burst`` takes
consecutive numbers; ``frame`` reads only the newest frame's Exif block when imgsrv's
counter has moved. Each frame is decoded into elphel-camd's capture TIFF
(`elphel_host.camera.nc393.frames`).
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from collections.abc import Mapping

import httpx

from elphel_host.camera.frames import CapturedBurst, CapturedFrame
from elphel_host.camera.nc393 import imgsrv
from elphel_host.camera.nc393.address import check_port
from elphel_host.camera.nc393.frames import decoded_frame, newest_stamp, tiff_pages
from elphel_host.camera.nc393.http import http_get
from elphel_host.camera.nc393.model import StockModel
from elphel_host.errors import CameraParameterError, UnsupportedError
from elphel_host.limits import HostLimits

# A capture waits for at most this many frames beyond the newest (elphel-camd's limit).
CAPTURE_AHEAD_MAX = 14


class StockFrames(ABC):
    """``frame``, ``capture`` and ``burst`` over one imgsrv client per sensor port."""

    _imgsrv: list[httpx.Client]
    _stamps: dict[int, tuple[int, tuple[int, int]]]
    _lock: threading.Lock
    limits: HostLimits

    @abstractmethod
    def params(self, port: int = 0, *, frame: int | None = None) -> dict[str, int]:
        """The port's parameters now (merged into each capture's metadata)."""

    @abstractmethod
    def model(self, port: int = 0) -> StockModel:
        """The parameter model of the port's sensor (its name and Bayer order)."""

    def frame(self, port: int = 0) -> dict[str, int]:
        """``port``, ``frame`` and ``timestamp_ns`` of the newest frame in imgsrv's buffer.

        imgsrv's ``/frame`` counter tells when a new frame has come; only then are the
        first KiB of the newest frame (``/bimg``, up to its Exif block) read for its
        number and time, so polling costs one small request per call.
        """
        counter = self._counter(port)
        with self._lock:
            cached = self._stamps.get(port)
        if cached is None or cached[0] != counter:
            cached = (counter, self._stamp(port))
            with self._lock:
                self._stamps[port] = cached
        number, stamp = cached[1]
        return {"port": port, "frame": number, "timestamp_ns": stamp}

    def _counter(self, port: int) -> int:
        check_port(port)
        client = self._imgsrv[port]
        url = str(client.base_url).rstrip("/") + imgsrv.FRAME
        answer = http_get(client, imgsrv.FRAME, limits=self.limits)
        return imgsrv.frame_number(answer.text, url=url)

    def _stamp(self, port: int) -> tuple[int, int]:
        client = self._imgsrv[port]

        def raw(data: bytes, kind: str, url: str) -> CapturedFrame:
            return self._decoded(port, data, kind, url, {})

        return newest_stamp(client, raw, limits=self.limits)

    def _fetch(
        self, port: int, path: str, params: Mapping[str, int] | None = None
    ) -> CapturedFrame:
        client = self._imgsrv[port]
        url = str(client.base_url).rstrip("/") + path
        response = http_get(client, path, limits=self.limits, frame=True)
        kind = imgsrv.image_type(response.headers.get("content-type"), url=url)
        return self._decoded(port, response.content, kind, url, params)

    def _decoded(
        self, port: int, data: bytes, kind: str, url: str, params: Mapping[str, int] | None
    ) -> CapturedFrame:
        model = self.model(port)
        now = self.params(port) if params is None else params
        return decoded_frame(
            data,
            kind,
            url=url,
            port=port,
            sensor=model.model,
            bayer=model.driver.bayer,
            params=now,
            bits=model.driver.bits,
        )

    def capture(self, port: int = 0, *, frame: int | None = None) -> CapturedFrame:
        """The next frame (``/towp/wait/bimg``), or frame ``frame`` from imgsrv's buffer.

        The metadata are an elphel-camd capture's: what the frame's Exif and MakerNote
        record (frame, time, exposure, gains, window, flips, Bayer order), ``port`` and
        ``sensor``, and the other parameters as in effect when the frame was fetched.
        ``frame`` may be one still to come (at most 14 ahead: waited for) or one still in
        the buffer: reached from the newest with imgsrv's ``prev`` moves (then from the
        read pointer that path saves) and checked by its number (`UnsupportedError` once
        it is overwritten). This moves imgsrv's global read pointer (``save``).
        """
        check_port(port)
        if frame is None:
            return self._fetch(port, imgsrv.NEXT)
        newest = self._counter(port)
        if frame > newest + CAPTURE_AHEAD_MAX:
            raise CameraParameterError(
                f"port {port}: frame {frame} is not taken yet (newest {newest}); "
                f"allowed: up to {newest + CAPTURE_AHEAD_MAX}",
                parameter="frame",
                value=frame,
                allowed=f"..{newest + CAPTURE_AHEAD_MAX}",
            )
        params = self.params(port)
        while frame > newest:
            got = self._fetch(port, imgsrv.NEXT, params)
            if got.frame == frame:
                return got
            newest = got.frame  # past it already (slow fetches): go back for it
        # Counted back from the newest, which may move on before imgsrv reads the path;
        # the place reached is saved as the read pointer, so a second try counts from
        # there, a place that stays put (another client's `save` may move it: a third try).
        got = self._fetch(port, imgsrv.back_path(newest - frame), params)
        for _ in range(2):
            if got.frame == frame:
                return got
            got = self._fetch(port, imgsrv.read_pointer_path(frame - got.frame), params)
        if got.frame == frame:
            return got
        raise UnsupportedError(
            f"port {port}: frame {frame} is no longer in imgsrv's buffer (the oldest reached "
            f"was frame {got.frame}); fetch frames sooner, or more slowly triggered"
        )

    def burst(self, count: int, *, port: int = 0, frame: int | None = None) -> CapturedBurst:
        """``count`` consecutive frames (from the next one or ``frame``) as one TIFF.

        Frames the fetching falls behind are taken from imgsrv's buffer; one overwritten
        before it was fetched is an `UnsupportedError` naming it.
        """
        if count < 1:
            raise ValueError(f"burst count {count!r}; allowed: 1 or more")
        frames = [self.capture(port, frame=frame)]
        while len(frames) < count:
            frames.append(self.capture(port, frame=frames[0].frame + len(frames)))
        return tiff_pages(frames)
