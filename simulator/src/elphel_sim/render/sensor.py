"""A sensor's readout of radiance: colour filter, exposure, gains, noise, quantisation, flips.

`expose` turns radiance into DN through a `SensorModel` (shot and read noise from a
seeded generator, clipping to the ADC's range); `mosaic` and `bayer_channels` sample
colour through a Bayer filter; `read_out` forms a Bayer sensor's image from the radiance
of its window and its `Readout` (the window, exposure, gains and flips decoded from the
registers in effect), strip by strip for photo-finish.
"""

from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtri

from elphel_sim.render.radiance import Intrinsics, Window
from elphel_sim.world import FloatArray

F32 = NDArray[np.float32]

BAYER_PATTERNS = ("RGGB", "GRBG", "GBRG", "BGGR")
_CHANNEL = {"R": 0, "G": 1, "B": 2}


def bayer_channels(
    pattern: str, shape: tuple[int, int], *, row0: int = 0, col0: int = 0
) -> NDArray[np.intp]:
    """Colour index (0 R, 1 G, 2 B) of every pixel of a window of a Bayer sensor.

    ``pattern`` names the colours of the array's 2x2 cell at even rows/columns
    (e.g. ``"GRBG"``); ``row0, col0`` are the window's origin in the array.
    """
    if pattern not in BAYER_PATTERNS:
        raise ValueError(f"bayer pattern {pattern!r}; allowed: {', '.join(BAYER_PATTERNS)}")
    cell = np.array(
        [[_CHANNEL[pattern[0]], _CHANNEL[pattern[1]]], [_CHANNEL[pattern[2]], _CHANNEL[pattern[3]]]]
    )
    r = (row0 + np.arange(shape[0])) % 2
    c = (col0 + np.arange(shape[1])) % 2
    out: NDArray[np.intp] = cell[r[:, None], c[None, :]]
    return out


def mosaic(rgb: FloatArray, pattern: str | None, *, row0: int = 0, col0: int = 0) -> FloatArray:
    """Sample an RGB radiance image through a Bayer filter (None: a mono sensor, mean of RGB)."""
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must have shape (H, W, 3), got {rgb.shape}")
    if pattern is None:
        mono: FloatArray = rgb.mean(axis=2)
        return mono
    ch = bayer_channels(pattern, rgb.shape[:2], row0=row0, col0=col0)
    out: FloatArray = np.take_along_axis(rgb, ch[..., None], axis=2)[..., 0]
    return out


@dataclass(frozen=True)
class SensorModel:
    """Photon-to-DN conversion of a sensor.

    Parameters
    ----------
    bits
        ADC depth; output is clipped to 0 .. 2**bits - 1.
    electrons_per_us
        Electrons collected per microsecond at radiance 1.0 (scene illumination x QE).
    full_well_e
        Saturation charge.
    dn_per_e
        Conversion gain at analog gain 1.0.
    read_noise_e
        Gaussian read noise (electrons RMS).
    black_level_dn
        Offset added to every pixel.
    """

    bits: int = 12
    electrons_per_us: float = 0.1
    full_well_e: float = 8000.0
    dn_per_e: float = 0.5
    read_noise_e: float = 3.0
    black_level_dn: float = 0.0


def expose(
    radiance: NDArray[np.floating],
    *,
    exposure_us: float,
    gain: float | NDArray[np.floating] = 1.0,
    model: SensorModel = SensorModel(),
    rng: np.random.Generator | None = None,
) -> NDArray[np.uint16]:
    """Integrate radiance into quantised DN.

    Parameters
    ----------
    radiance
        Per-pixel radiance (after the colour filter), any shape.
    exposure_us
        Integration time.
    gain
        Analog gain, a scalar or an array broadcastable to ``radiance`` (per-colour gains).
    model
        The sensor's conversion.
    rng
        Source of shot and read noise; None renders the noise-free expectation.
    """
    if exposure_us < 0:
        raise ValueError(f"exposure_us={exposure_us}; allowed: >= 0")
    # one new array in the radiance's float type, then in place (forming a frame is the
    # simulated board's hot path: float32 radiance keeps the whole chain in float32)
    electrons = np.multiply(radiance, exposure_us * model.electrons_per_us)
    np.clip(electrons, 0.0, model.full_well_e, out=electrons)
    if rng is not None:
        electrons = _shot_and_read_noise(electrons, model.read_noise_e, rng)
    dn = electrons
    dn *= model.dn_per_e
    dn *= gain
    dn += model.black_level_dn
    np.rint(dn, out=dn)
    np.clip(dn, 0, (1 << model.bits) - 1, out=dn)
    out: NDArray[np.uint16] = dn.astype(np.uint16)
    return out


# Below this many electrons a pixel's shot noise is drawn from the Poisson law itself; at
# and above it, shot plus read noise is one normal draw of the same mean and variance
# (mean + read_noise**2). At 30 e- the Poisson law's skewness is 0.18 and falls as one
# over the root of the count, and one normal draw costs a fraction of a Poisson draw plus
# a normal one: forming is the simulated board's hot path under `elphel-camd --board sim`.
POISSON_EXACT_BELOW_E = 30.0


# The standard normal law's quantiles at the middles of 65536 equally likely bins: a
# frame's normal draws are 16-bit random integers looked up here, 14 ms for a full frame
# against 43 ms for NumPy's ziggurat (standard deviation 0.99999, tails cut at 4.32).
_NORMAL_QUANTILES = ndtri((np.arange(65536) + 0.5) / 65536).astype(np.float32)


def standard_normal(rng: np.random.Generator, shape: tuple[int, ...]) -> NDArray[np.float32]:
    """Standard normal float32 draws of ``shape`` (65536 levels, see above)."""
    # the generator's raw 64-bit words, four 16-bit indices each (2.8 ms for a full
    # frame against 5.1 ms for ``rng.integers``)
    n = int(np.prod(shape))
    index = rng.bit_generator.random_raw(-(-n // 4)).view(np.uint16)[:n].reshape(shape)
    out: NDArray[np.float32] = _NORMAL_QUANTILES[index]
    return out


def _shot_and_read_noise(
    electrons: NDArray[np.floating], read_noise_e: float, rng: np.random.Generator
) -> NDArray[np.floating]:
    sigma = electrons + read_noise_e**2
    np.sqrt(sigma, out=sigma)
    noisy: NDArray[np.floating] = standard_normal(rng, electrons.shape).astype(
        electrons.dtype, copy=False
    )
    noisy *= sigma
    noisy += electrons
    low = electrons < POISSON_EXACT_BELOW_E
    if low.any():
        dim = electrons[low]
        noisy[low] = rng.poisson(dim) + rng.normal(0.0, read_noise_e, dim.shape)
    return noisy


@dataclass(frozen=True)
class Readout:
    """How a Bayer sensor reads a frame, decoded from its registers in effect."""

    left: int
    top: int
    width: int
    height: int
    exposure_us: float
    gains: tuple[float, float, float, float]  # red, green on red rows, green on blue rows, blue
    fliph: bool
    flipv: bool
    bayer: str  # the array's colour cell at even rows and columns

    def window_on(self, intrinsics: Intrinsics) -> Window:
        """The window read out, as far as it lies on the sensor's array."""
        width = min(self.width, intrinsics.width - self.left)
        height = min(self.height, intrinsics.height - self.top)
        return (self.left, self.top, width, height)


def read_out(
    radiance: FloatArray, readout: Readout, *, model: SensorModel, rng: np.random.Generator | None
) -> NDArray[np.uint16]:
    """Read radiance out as a Bayer sensor does: colour filter, gains, exposure, flips.

    Parameters
    ----------
    radiance
        ``(strips, height, width, 3)`` linear RGB radiance of the window read out
        (`render_strips` of ``readout.window_on(intrinsics)``), one entry per strip;
        only read (it may be the read-only radiance `render_strips` keeps for reuse).
    readout
        The window's origin on the array (it sets the Bayer phase), the exposure, the
        per-colour gains, the flips and the colour filter.
    model
        The sensor's conversion to DN.
    rng
        Source of shot and read noise; None renders the noise-free expectation.

    Returns
    -------
    numpy.ndarray
        uint16, ``(strips * height, width)``: the strips one below the other.
    """
    strips, height, width = radiance.shape[:3]
    raw, gain = _filtered(radiance, readout)
    image = expose(raw, exposure_us=readout.exposure_us, gain=gain[None], model=model, rng=rng)
    if readout.fliph:
        image = image[:, :, ::-1]
    if readout.flipv:
        image = image[:, ::-1, :]
    return np.ascontiguousarray(image.reshape(strips * height, width))


# The colour-filtered radiance of the last few read-only radiances (a still scene's,
# which `render_strips` keeps for reuse and hands out as a new view each time), keyed by
# the array that owns the memory, the view's place in it and the filter's phase: a full
# frame's four strided copies cost 18 ms of 50. The per-pixel gains are kept apart (a
# PATCH of one gain must not form the filtered radiance again).
_FilterKey = tuple[int, int, tuple[int, ...], tuple[int, ...], str, int, int]
_FILTERED: dict[_FilterKey, tuple[weakref.ref[np.ndarray], F32]] = {}
_GainKey = tuple[tuple[int, int], str, int, int, tuple[float, ...]]
_GAINS: dict[_GainKey, F32] = {}
_KEEP = 2
_filtered_lock = threading.Lock()


def _owner(array: np.ndarray) -> np.ndarray:
    """The array that owns ``array``'s memory (itself if it is not a view)."""
    while isinstance(array.base, np.ndarray):
        array = array.base
    return array


def _keep(cache: dict[Any, Any], key: object, value: object) -> None:
    with _filtered_lock:
        while len(cache) >= _KEEP:
            del cache[next(iter(cache))]
        cache[key] = value


def _filtered(radiance: FloatArray, readout: Readout) -> tuple[F32, F32]:
    """The radiance through the colour filter (float32) and the per-pixel gain."""
    strips, height, width = radiance.shape[:3]
    # the colour filter repeats every 2x2 pixels: each of the four phases is one strided
    # copy of its colour (in float32: DN need 12 bits, float32 carries 24) and one gain
    cell = bayer_channels(readout.bayer, (2, 2), row0=readout.top, col0=readout.left)
    phase = (readout.bayer, readout.top & 1, readout.left & 1)
    gain_key = ((height, width), *phase, readout.gains)
    with _filtered_lock:
        gain = _GAINS.get(gain_key)
    if gain is None:
        red, green_r, green_b, blue = readout.gains
        gain = np.empty((height, width), dtype=np.float32)
        for dy in range(2):
            green = green_b if 2 in cell[dy] else green_r  # green shares its rows with blue or red
            for dx in range(2):
                gain[dy::2, dx::2] = (red, green, blue)[int(cell[dy, dx])]
        gain.flags.writeable = False
        _keep(_GAINS, gain_key, gain)
    owner = _owner(radiance)
    reuse = not radiance.flags.writeable and not owner.flags.writeable
    key = (
        id(owner),
        radiance.__array_interface__["data"][0],
        radiance.shape,
        radiance.strides,
        *phase,
    )
    if reuse:
        with _filtered_lock:
            hit = _FILTERED.get(key)
        if hit is not None and hit[0]() is owner:
            return hit[1], gain
    raw = np.empty((strips, height, width), dtype=np.float32)
    for dy in range(2):
        for dx in range(2):
            raw[:, dy::2, dx::2] = radiance[:, dy::2, dx::2, int(cell[dy, dx])]
    if reuse:
        raw.flags.writeable = False
        _keep(_FILTERED, key, (weakref.ref(owner), raw))
    return raw, gain
