"""One elphel-camd sensor port as a Micro-Manager camera (16-bit frames, hardware ROI).

Exposure is ``EXPOS`` in ms (the daemon's µs / 1000); the ROI is the sensor window
(``WOI_LEFT``, ``WOI_TOP``, ``WOI_WIDTH``, ``WOI_HEIGHT``, in full-sensor pixels, even on
a Bayer sensor). The Exposure limits are the daemon's for the current window: they come
from elphel-camd's own sensor model (`elphel_host.camera.nc393.model`), the same code
the daemon checks a change with, so the upper limit is accepted and one µs more is not.
The sensor rounds exposure to whole rows, so a value read back may differ from the one
set by up to one row time (tens of µs), and it moves by a few µs when the window width
changes.

Binning: elphel-camd has no binning parameter, so ``Binning`` allows only 1.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import DTypeLike
from pymmcore_plus.core import Keyword
from pymmcore_plus.experimental.unicore import CameraDevice

from elphel_host.camera.client import CameraClient, CameraHTTPError
from elphel_host.camera.nc393.model import StockModel
from elphel_host.errors import CameraClientError, CameraParameterError, UnsupportedError

_RANGE = re.compile(r"(-?\d+)\.\.(-?\d+)")
_WINDOW = ("WOI_LEFT", "WOI_TOP", "WOI_WIDTH", "WOI_HEIGHT")


def _range_of(error: CameraParameterError) -> tuple[int, int]:
    found = _RANGE.search(error.allowed)
    if found is None:
        raise CameraClientError(
            f"{error.parameter}: no numeric range in what is allowed ({error.allowed!r})"
        )
    return int(found.group(1)), int(found.group(2))


class ElphelCameraDevice(CameraDevice):
    """A sensor port of an elphel-camd daemon, 16-bit frames (``uint16``).

    Parameters
    ----------
    url
        The daemon's URL, ``http://HOST:PORT``.
    token
        Its bearer token (exposure and ROI changes and captures need it).
    port
        The sensor port.
    """

    def __init__(self, url: str, token: str | None = None, *, port: int = 0) -> None:
        super().__init__()
        self.url = url
        self.token = token
        self.port = int(port)
        self._client: CameraClient | None = None
        self._model: StockModel | None = None
        self._params: dict[str, int] = {}
        self._full: tuple[int, int] = (0, 0)  # sensor width, height
        self._effective_frame: int | None = None  # first frame with the last change in effect
        self.register_property("URL", default_value=url, is_read_only=True)
        self.register_property("Port", default_value=self.port, is_read_only=True)
        self.register_property(
            "Sensor", property_type=str, getter=type(self)._get_sensor, is_read_only=True
        )
        self.register_property(
            "Bayer", property_type=str, getter=type(self)._get_bayer, is_read_only=True
        )
        self._sensor: dict[str, Any] = {}

    # -- lifecycle ------------------------------------------------------------------------

    def initialize(self) -> None:
        client = CameraClient(self.url, self.token)
        self._client = client
        ports = {p["port"]: p for p in client.info()["ports"]}
        entry = ports.get(self.port)
        if entry is None or entry.get("sensor") is None:
            have = ", ".join(str(p) for p, e in sorted(ports.items()) if e.get("sensor"))
            raise CameraClientError(
                f"camera {self.url}: port {self.port} has no sensor; ports with one: {have}"
            )
        self._sensor = dict(entry["sensor"])
        self._model = StockModel(int(self._sensor["sensor_code"]), port=self.port)
        full = self._model.driver.defaults()  # the whole sensor, as after init
        self._full = (int(full["WOI_WIDTH"]), int(full["WOI_HEIGHT"]))
        self.set_property_allowed_values(Keyword.Binning, [1])
        self._refresh()

    def shutdown(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    @property
    def client(self) -> CameraClient:
        if self._client is None:
            raise CameraClientError(f"camera {self.url} is not initialised (load it into a core)")
        return self._client

    def _refresh(self, params: Mapping[str, int] | None = None) -> None:
        """Take the parameters in effect (read now if not given); set the Exposure limits."""
        self._params = dict(params) if params is not None else self.client.params(self.port)
        limits = self.exposure_limits_us()
        if limits is not None:
            self.set_property_limits(Keyword.Exposure, (limits[0] / 1000.0, limits[1] / 1000.0))

    def exposure_limits_us(self) -> tuple[int, int] | None:
        """EXPOS limits (µs) in the current window; None if the sensor has no exposure."""
        assert self._model is not None
        try:
            self._model.check(self._params, {"EXPOS": 0x7FFFFFFF})
        except CameraParameterError as e:
            return _range_of(e)
        except UnsupportedError:
            return None
        return 1, 0x7FFFFFFF

    def _set(self, changes: Mapping[str, int]) -> None:
        applied = self.client.set_params(dict(changes), port=self.port)
        self._effective_frame = applied.frame
        self._refresh(applied.params)

    # -- exposure -------------------------------------------------------------------------

    def get_exposure(self) -> float:
        return self._params["EXPOS"] / 1000.0

    def set_exposure(self, exposure: float) -> None:
        """Set EXPOS to ``exposure`` ms (whole µs; the sensor rounds it to whole rows)."""
        self._set({"EXPOS": round(float(exposure) * 1000.0)})

    # -- image geometry -------------------------------------------------------------------

    def shape(self) -> tuple[int, int]:
        return self._params["WOI_HEIGHT"], self._params["WOI_WIDTH"]

    def dtype(self) -> DTypeLike:
        return np.uint16

    def get_roi(self) -> tuple[int, int, int, int]:
        p = self._params
        return p["WOI_LEFT"], p["WOI_TOP"], p["WOI_WIDTH"], p["WOI_HEIGHT"]

    def set_roi(self, x: int, y: int, width: int, height: int) -> None:
        """Set the sensor window (full-sensor pixels); a Bayer sensor takes even values.

        Odd values are refused with the reason (the daemon's: "even"), never rounded.
        """
        changes = dict(zip(_WINDOW, (int(x), int(y), int(width), int(height)), strict=True))
        self._set(changes)

    def clear_roi(self) -> None:
        width, height = self._full
        self._set(dict(zip(_WINDOW, (0, 0, width, height), strict=True)))

    # -- acquisition ----------------------------------------------------------------------

    def start_sequence(
        self,
        n: int | None,
        get_buffer: Callable[[Sequence[int], DTypeLike], np.ndarray],
    ) -> Iterator[Mapping]:
        """Consecutive frames of the port: the first, then each next one by its number.

        Frame N+1 is asked for by number (``capture?frame=N+1``): the daemon waits for it
        or takes it from its ring buffer, so no frame is skipped while one is being sent.
        """
        done = 0
        wanted = self._first_frame()
        while n is None or done < n:
            try:
                frame = self.client.capture(self.port, frame=wanted)
            except CameraHTTPError as e:
                # The frame asked for went by before the daemon could send it (its ring
                # buffer and parameter history are bounded; a slow first render in the
                # simulator can outlast them): go on from the next frame.
                if e.body.get("error") != "frame_not_available":
                    raise
                frame = self.client.capture(self.port)
            buffer = get_buffer(frame.image.shape, np.uint16)
            buffer[:] = frame.image
            done += 1
            wanted = frame.frame + 1
            yield self._metadata(frame.metadata)

    def _first_frame(self) -> int | None:
        """The frame to start from: the first with the last change in effect, if still ahead.

        Without it the next frame could be one taken before the change (a snap after
        setExposure must show the new exposure).
        """
        if self._effective_frame is None:
            return None
        wanted, self._effective_frame = self._effective_frame, None
        if wanted > int(self.client.frame(self.port)["frame"]):
            return wanted
        return None

    def _metadata(self, metadata: Mapping[str, Any]) -> dict[str, str]:
        """The frame's daemon metadata as Micro-Manager tags (strings), prefixed Elphel-."""
        tags = {
            f"Elphel-{key}": str(value)
            for key, value in metadata.items()
            if isinstance(value, int | float | str)
        }
        tags[Keyword.Exposure] = f"{metadata.get('EXPOS', self._params['EXPOS']) / 1000.0:.3f}"
        return tags

    # -- read-only properties -------------------------------------------------------------

    def _get_sensor(self) -> str:
        return str(self._sensor.get("model", ""))

    def _get_bayer(self) -> str:
        return str(self._sensor.get("bayer") or "mono")
