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

from elphel_host.camera.nc393 import imgsrv, parsedit
from elphel_host.camera.nc393.address import PORTS, NC393Address, check_port, parse_nc393_url
from elphel_host.camera.nc393.capture import StockFrames
from elphel_host.camera.nc393.http import http_get
from elphel_host.camera.nc393.model import STOCK_ONLY, Checked, StockModel, port_entry
from elphel_host.camera.staging import Applied, Staging
from elphel_host.camera.unsupported import NoEventsNoRegisters
from elphel_host.closing import Closing
from elphel_host.errors import CameraClientError, CameraParameterError, UnsupportedError
from elphel_host.limits import HostLimits

# Read with every parameter listing when the camera has them (the model needs the rest).
_EXTRA = ("FP1000S", "COLOR", "BITS", "QUALITY")


class NC393Client(StockFrames, NoEventsNoRegisters, Staging, Closing):
    """A stock Elphel NC393, through its own web server and imgsrv.

    Parameters
    ----------
    address
        An `NC393Address` or an ``nc393://HOST[:HTTP_PORT][?imgsrv=BASE]`` URL.
    timeout_s
        Per-request timeout, and how long a change may take to come into effect. A frame
        from imgsrv may be longer in coming (``wait`` for the next one, a busy camera):
        its reads wait up to the request deadline (``limits.deadline_s``) if longer.
    transport
        httpx transport to use instead of the network (tests); shared by all services.
    limits
        Sizes and deadlines the camera's answers are held to (default: `HostLimits.from_env`).

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
        limits: HostLimits | None = None,
    ) -> None:
        self.address = parse_nc393_url(address) if isinstance(address, str) else address
        self.url = self.address.url
        self.timeout_s = timeout_s
        self.limits = HostLimits.from_env() if limits is None else limits
        self._web = httpx.Client(
            base_url=self.address.parsedit_url, timeout=timeout_s, transport=transport
        )
        frames = httpx.Timeout(timeout_s, read=max(timeout_s, self.limits.deadline_s))
        self._imgsrv = [
            httpx.Client(base_url=self.address.imgsrv_url(p), timeout=frames, transport=transport)
            for p in range(PORTS)
        ]
        self._models: dict[int, StockModel] = {}
        self._stamps: dict[int, tuple[int, tuple[int, int]]] = {}
        self._lock = threading.Lock()

    def close(self) -> None:
        self._web.close()
        for client in self._imgsrv:
            client.close()

    # -- plumbing --------------------------------------------------------------------------

    def _parsedit(self, query: str, names: tuple[str, ...]) -> dict[str, int]:
        path = f"{parsedit.PATH}?{query}"
        response = http_get(self._web, path, limits=self.limits)
        url = str(self._web.base_url).rstrip("/") + path
        return parsedit.parse_answer(response.text, url=url, names=names)

    def _sensor_code(self, port: int) -> int:
        check_port(port)
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

        A stock camera cannot tell chip ids or I2C addresses; ``bits`` is the sensor's depth,
        the scale of the decoded frames.
        """
        ports = []
        for port in range(PORTS):
            got = self._parsedit(parsedit.read_query(port, ["SENSOR", "FRAME"]), ("SENSOR",))
            entry = port_entry(port, got["SENSOR"], got.get("FRAME"))
            ports.append(entry)
        return {
            "board": "nc393",
            "daemon": "Elphel stock firmware (parsedit.php, imgsrv)",
            "version": None,  # parsedit.php and imgsrv do not report one
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
        check_port(port)
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

    def _set_params(
        self, changes: Mapping[str, int], port: int, frame: int | None, ahead: int | None
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
        model, now, checked, stock = self._checked(port, changes)
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

    def set_params_ports(
        self,
        changes: Mapping[str, int],
        ports: tuple[int, ...] | list[int],
        *,
        ahead: int | None = None,
    ) -> dict[int, Applied]:
        """The same change on several ports in ONE request (``NAME=value*K!MASK``).

        Each port's change is checked against its own sensor's model first: nothing is
        written if one fails. K is ``ahead``, else the largest of the ports' earliest.
        The answer holds the first port's FRAME, so its frame is exact; another port's is
        its FRAME read just before, plus the frames the first port advanced meanwhile,
        plus K (exact when the ports share one frame clock or trigger). Every port is
        read back once its frame has begun. ``TRIG_PERIOD`` is taken by the
        ``TRIG_MASTER`` port only (the others copy it), as with `set_params`.
        """
        order = sorted(set(ports))
        if not order:
            raise ValueError("set_params_ports(): give at least one sensor port")
        for p in order:
            check_port(p)
        checked = {p: self._checked(p, changes) for p in order}
        k = max(c[2].min_ahead for c in checked.values()) if ahead is None else ahead
        for model, now, chk, _ in checked.values():
            model.ahead_for(chk, current=now["FRAME"], frame=None, ahead=k)
        first = order[0]
        mask = sum(1 << p for p in order)
        query = parsedit.write_query(first, changes, ahead=k, mask=mask, read=("FRAME",))
        moved = self._parsedit(query, ("FRAME",))["FRAME"] - checked[first][1]["FRAME"]
        out = {}
        for p, (model, now, chk, stock) in checked.items():
            target = now["FRAME"] + moved + k
            out[p] = Applied(frame=target, params=self._confirm(p, model, chk, target, stock))
        return out

    def _checked(
        self, port: int, changes: Mapping[str, int]
    ) -> tuple[StockModel, dict[str, int], Checked, tuple[str, ...]]:
        """The port's model, its state now (with FRAME), the checked change, its stock names."""
        model = self.model(port)
        stock = tuple(n for n in changes if n in STOCK_ONLY)
        now = self._parsedit(
            parsedit.read_query(port, (*model.state_names, "FRAME", *stock)),
            (*model.state_names, "FRAME"),
        )
        return model, now, model.check(now, changes), stock

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

    def trigger(self, port: int = 0) -> None:
        """Fire one internal trigger (imgsrv ``/trig``); the port must be in snapshot mode.

        Raises
        ------
        CameraParameterError
            The port's TRIG lacks the snapshot bit 4.
        """
        check_port(port)
        trig = self.params(port, names=("TRIG",))["TRIG"]
        if not trig & 4:
            raise CameraParameterError(
                f"port {port}: TRIG={trig}: one trigger needs snapshot mode; allowed: 4 or 20",
                parameter="TRIG",
                value=trig,
                allowed="4 or 20 (snapshot)",
            )
        http_get(self._imgsrv[port], imgsrv.TRIGGER, limits=self.limits)
