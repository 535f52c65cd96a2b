"""The stock NC393 backend: `NC393Client` over parsedit.php and imgsrv (Elphel's firmware).

Nothing of ours runs on the camera. Parameters go through parsedit.php, checked first
against elphel-camd's parameter model for the sensor found (`stock_model`), written in ONE
request as ``NAME=value*K`` and read back once in effect. A stock camera cannot make
several parameters all-or-nothing: the model refuses a bad change before anything is
written, but if the camera itself takes only part of a change, the read-back names what
differs and nothing undoes the rest. Frames come from imgsrv and are decoded (JP4, JP46,
JPEG or raw TIFF) into the same 16-bit TIFF with JSON metadata an elphel-camd capture is.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from typing import Any

import httpx

from elphel_host.camera import imgsrv, parsedit
from elphel_host.camera.frames import CapturedBurst, CapturedFrame
from elphel_host.camera.nc393_address import NC393Address, parse_nc393_url
from elphel_host.camera.nc393_frames import decoded_frame, tiff_pages
from elphel_host.camera.staging import Applied, Staging
from elphel_host.camera.stock_model import STOCK_ONLY, Checked, StockModel, port_entry
from elphel_host.camera.unsupported import NoEventsNoRegisters
from elphel_host.closing import Closing
from elphel_host.errors import CameraClientError, CameraParameterError, UnsupportedError

PORTS = 4
# Read with every parameter listing when the camera has them (the model needs the rest).
_EXTRA = ("FP1000S", "COLOR", "BITS", "QUALITY")
# A capture waits for at most this many frames beyond the newest (elphel-camd's limit).
CAPTURE_AHEAD_MAX = 14


class NC393Client(NoEventsNoRegisters, Staging, Closing):
    """A stock Elphel NC393, through its own web server and imgsrv.

    Parameters
    ----------
    address
        An `NC393Address` or an ``nc393://HOST[:HTTP_PORT][?imgsrv=BASE]`` URL.
    timeout_s
        Per-request timeout, and how long a change may take to come into effect.
    transport
        httpx transport to use instead of the network (tests); shared by all services.

    Examples
    --------
    >>> with NC393Client("nc393://192.168.0.9") as cam:  # doctest: +SKIP
    ...     applied = cam.set_params({"EXPOS": 5000}, ahead=4)
    ...     frame = cam.capture()
    """

    def __init__(
        self,
        address: NC393Address | str,
        *,
        timeout_s: float = 30.0,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        self.address = parse_nc393_url(address) if isinstance(address, str) else address
        self.url = self.address.url
        self.timeout_s = timeout_s
        self._web = httpx.Client(
            base_url=self.address.parsedit_url, timeout=timeout_s, transport=transport
        )
        self._imgsrv = [
            httpx.Client(
                base_url=self.address.imgsrv_url(p), timeout=timeout_s, transport=transport
            )
            for p in range(PORTS)
        ]
        self._models: dict[int, StockModel] = {}
        self._newest: dict[int, tuple[int, CapturedFrame]] = {}
        self._lock = threading.Lock()

    def close(self) -> None:
        self._web.close()
        for client in self._imgsrv:
            client.close()

    # -- plumbing --------------------------------------------------------------------------

    def _get(self, client: httpx.Client, path: str) -> httpx.Response:
        where = str(client.base_url).rstrip("/") + path
        try:
            response = client.get(path)
        except httpx.HTTPError as e:
            raise CameraClientError(f"cannot reach the camera at {where}: {e}") from e
        if response.status_code >= 400:
            first = response.text.strip().splitlines()[0][:120] if response.text.strip() else ""
            raise CameraClientError(f"{where}: HTTP {response.status_code}: {first!r}")
        return response

    def _parsedit(self, query: str, names: tuple[str, ...]) -> dict[str, int]:
        path = f"{parsedit.PATH}?{query}"
        response = self._get(self._web, path)
        url = str(self._web.base_url).rstrip("/") + path
        return parsedit.parse_answer(response.text, url=url, names=names)

    def _check_port(self, port: int) -> None:
        if not (isinstance(port, int) and 0 <= port < PORTS):
            raise ValueError(f"sensor port {port!r}; allowed: 0..{PORTS - 1}")

    def _sensor_code(self, port: int) -> int:
        self._check_port(port)
        return self._parsedit(parsedit.read_query(port, ["SENSOR"]), ("SENSOR",))["SENSOR"]

    def model(self, port: int = 0) -> StockModel:
        """The parameter model of the sensor on a port (read once, from ``SENSOR``).

        Raises
        ------
        CameraClientError
            No sensor on the port (``SENSOR`` 0).
        UnsupportedError
            A sensor without a parameter model here (the Boson 640).
        """
        with self._lock:
            known = self._models.get(port)
        if known is not None:
            return known
        code = self._sensor_code(port)
        if code == 0:
            raise CameraClientError(f"{self.url}: port {port} has no sensor (SENSOR 0)")
        model = StockModel(code, port=port)
        with self._lock:
            self._models[port] = model
        return model

    # -- board -----------------------------------------------------------------------------

    def info(self) -> dict[str, Any]:
        """Ports and their sensors as ``SENSOR`` names them, shaped like elphel-camd's /info.

        A stock camera cannot tell chip ids or I2C addresses; ``bits`` is 16, the depth of
        the decoded frames.
        """
        ports = []
        for port in range(PORTS):
            got = self._parsedit(parsedit.read_query(port, ["SENSOR", "FRAME"]), ("SENSOR",))
            entry = port_entry(port, got["SENSOR"], got.get("FRAME"))
            ports.append(entry)
        return {
            "board": "nc393",
            "daemon": "Elphel stock firmware (parsedit.php, imgsrv)",
            "version": "unknown",
            "capabilities": ["capture", "frames", "trigger"],
            "ports": ports,
        }

    # -- parameters ------------------------------------------------------------------------

    def params(
        self, port: int = 0, *, frame: int | None = None, names: tuple[str, ...] | None = None
    ) -> dict[str, int]:
        """Parameters in effect now, read with one parsedit.php request.

        ``names`` picks some (default: every parameter of the sensor's model, with
        ``FP1000S``, ``COLOR``, ``BITS`` and ``QUALITY`` where the camera has them, and
        ``FRAME``). ``frame`` may only name the current frame: parsedit.php keeps no
        history (`UnsupportedError` otherwise).
        """
        self._check_port(port)
        if names is None:
            required = (*self.model(port).state_names, "SENSOR", "FRAME")
            asked = (*required, *_EXTRA)
        else:
            required = asked = (*names, "FRAME") if "FRAME" not in names else tuple(names)
        got = self._parsedit(parsedit.read_query(port, asked), required)
        if frame is not None and frame != got["FRAME"]:
            raise UnsupportedError(
                f"parameters of frame {frame}: a stock NC393 reports only the current frame's "
                f"(now {got['FRAME']}); parsedit.php keeps no history"
            )
        return got if names is None or "FRAME" in names else {n: got[n] for n in names}

    def set_params(
        self,
        changes: Mapping[str, int],
        *,
        port: int = 0,
        frame: int | None = None,
        ahead: int | None = None,
    ) -> Applied:
        """Check, write in one request ``ahead`` frames on (or at ``frame``), confirm.

        The change is checked against elphel-camd's model of the port's sensor before
        anything is written, then sent as ``NAME=value*K``. K is ``ahead``; for ``frame=N``
        it is N minus the current frame; with neither, the smallest the change's program
        functions allow (their latency + 1, as elphel-camd). K must lie between that and 6
        (parsedit.php's maxahead: further ahead the script blocks). Once the target frame
        has begun, the parameters are read back: a value other than the one asked raises.

        NOT all-or-nothing: the stock camera applies the names one by one; a parameter the
        camera refuses or changes after the check is reported, not rolled back.

        Raises
        ------
        CameraParameterError
            A value out of range, or K too small (nothing written).
        UnsupportedError
            A parameter the sensor does not take, or K beyond 6 frames (nothing written).
        ReadBackError
            The camera reports another value once the change is in effect.
        CameraClientError
            ``frame=N`` missed (a frame began between reading FRAME and writing), the
            frame never came, or the camera could not be reached.
        """
        if frame is not None and ahead is not None:
            raise ValueError("give frame or ahead, not both")
        model = self.model(port)
        stock = tuple(n for n in changes if n in STOCK_ONLY)
        now = self._parsedit(
            parsedit.read_query(port, (*model.state_names, "FRAME", *stock)),
            (*model.state_names, "FRAME"),
        )
        checked = model.check(now, changes)
        current = now["FRAME"]
        k = model.ahead_for(checked, current=current, frame=frame, ahead=ahead)
        query = parsedit.write_query(port, changes, ahead=k, read=("FRAME",))
        answer = self._parsedit(query, ("FRAME",))
        target = answer["FRAME"] + k
        if frame is not None and target != frame:
            raise CameraClientError(
                f"port {port}: frame {frame} missed: a frame began between reading FRAME "
                f"({current}) and writing; the change is in effect from frame {target}"
            )
        found = self._confirm(port, model, checked, target, stock)
        return Applied(frame=target, params=found)

    def _confirm(
        self, port: int, model: StockModel, checked: Checked, target: int, stock: tuple[str, ...]
    ) -> dict[str, int]:
        """Wait until frame ``target`` has begun; read back and compare what was asked."""
        names = (*model.state_names, "FRAME", *stock)
        fps1000 = int(checked.state.get("FP1000S") or 0)
        poll_s = min(0.1, max(0.005, 333.0 / fps1000)) if fps1000 > 0 else 0.05
        deadline = time.monotonic() + self.timeout_s
        while True:
            got = self._parsedit(parsedit.read_query(port, names), names)
            if got["FRAME"] >= target:
                break
            if time.monotonic() > deadline:
                raise CameraClientError(
                    f"port {port}: frame {target} did not come within {self.timeout_s:g} s "
                    f"(FRAME is {got['FRAME']}); is the sensor running, the trigger on?"
                )
            time.sleep(poll_s)
        model.check_read_back(checked, got)
        return got

    # -- frames ----------------------------------------------------------------------------

    def frame(self, port: int = 0) -> dict[str, int]:
        """``port``, ``frame`` and ``timestamp_ns`` of the newest complete frame.

        imgsrv's ``/frame`` counter tells when a new frame has come; only then is the
        newest frame fetched (``/bimg``) to read its number and time, so polling costs one
        small request per call and one frame per new frame.
        """
        newest = self._newest_frame(port)
        return {
            "port": port,
            "frame": newest.frame,
            "timestamp_ns": int(newest.metadata["timestamp_ns"]),
        }

    def _newest_frame(self, port: int) -> CapturedFrame:
        self._check_port(port)
        client = self._imgsrv[port]
        counter = imgsrv.frame_number(
            self._get(client, imgsrv.FRAME).text,
            url=str(client.base_url).rstrip("/") + imgsrv.FRAME,
        )
        with self._lock:
            cached = self._newest.get(port)
        if cached is not None and cached[0] == counter:
            return cached[1]
        got = self._fetch(port, imgsrv.NEWEST)
        with self._lock:
            self._newest[port] = (counter, got)
        return got

    def _fetch(
        self, port: int, path: str, params: Mapping[str, int] | None = None
    ) -> CapturedFrame:
        client = self._imgsrv[port]
        url = str(client.base_url).rstrip("/") + path
        response = self._get(client, path)
        kind = imgsrv.image_type(response.headers.get("content-type"), url=url)
        model = self.model(port)
        now = self.params(port) if params is None else params
        return decoded_frame(
            response.content,
            kind,
            url=url,
            port=port,
            sensor=model.model,
            bayer=model.driver.bayer,
            params=now,
        )

    def capture(self, port: int = 0, *, frame: int | None = None) -> CapturedFrame:
        """The next frame (``/towp/wait/bimg``), or frame ``frame`` if it is the newest.

        The metadata are an elphel-camd capture's: what the frame's Exif and MakerNote
        record (frame, time, exposure, gains, window, flips, Bayer order), ``port`` and
        ``sensor``, and the other parameters as in effect when the frame was fetched.
        ``frame`` may name the newest frame or one still to come (at most 14 ahead):
        imgsrv keeps older frames, but not addressed by number (`UnsupportedError`).
        """
        self._check_port(port)
        if frame is None:
            return self._fetch(port, imgsrv.NEXT)
        newest = self._newest_frame(port)
        if newest.frame == frame:
            return newest
        if frame < newest.frame:
            raise UnsupportedError(
                f"port {port}: frame {frame} is no longer the newest (frame {newest.frame} "
                "is); a stock NC393's imgsrv serves the newest frame and those to come"
            )
        if frame > newest.frame + CAPTURE_AHEAD_MAX:
            raise CameraParameterError(
                f"port {port}: frame {frame} is not taken yet (newest {newest.frame}); "
                f"allowed: up to {newest.frame + CAPTURE_AHEAD_MAX}",
                parameter="frame",
                value=frame,
                allowed=f"..{newest.frame + CAPTURE_AHEAD_MAX}",
            )
        while True:
            got = self._fetch(port, imgsrv.NEXT)
            if got.frame == frame:
                return got
            if got.frame > frame:
                raise CameraClientError(
                    f"port {port}: frame {frame} was skipped: imgsrv's next frame was {got.frame}"
                )

    def burst(self, count: int, *, port: int = 0, frame: int | None = None) -> CapturedBurst:
        """``count`` consecutive frames, each ``/towp/wait/bimg``; a gap is an error.

        Raises
        ------
        CameraClientError
            A frame number was skipped: fetching and decoding is slower than the frame
            rate (lower it with FP1000SLIM, or use a trigger).
        """
        if count < 1:
            raise ValueError(f"burst count {count!r}; allowed: 1 or more")
        first = self.capture(port, frame=frame)
        frames = [first]
        params = self.params(port)
        while len(frames) < count:
            got = self._fetch(port, imgsrv.NEXT, params)
            if got.frame != frames[-1].frame + 1:
                raise CameraClientError(
                    f"port {port}: burst broken after {len(frames)} of {count} frames: frame "
                    f"{frames[-1].frame} then {got.frame}; fetching and decoding is slower "
                    "than the frame rate (lower FP1000SLIM or trigger the frames)"
                )
            frames.append(got)
        return tiff_pages(frames)

    def trigger(self, port: int = 0) -> None:
        """Fire one internal trigger (imgsrv ``/trig``); the port must be in snapshot mode.

        Raises
        ------
        CameraParameterError
            The port's TRIG lacks the snapshot bit 4.
        """
        self._check_port(port)
        trig = self.params(port, names=("TRIG",))["TRIG"]
        if not trig & 4:
            raise CameraParameterError(
                f"port {port}: TRIG={trig}: one trigger needs snapshot mode; allowed: 4 or 20",
                parameter="TRIG",
                value=trig,
                allowed="4 or 20 (snapshot)",
            )
        self._get(self._imgsrv[port], imgsrv.TRIGGER)
