"""JP4/JP46 round trip: the simulator's encoder, the host's decoder, a known 12-bit Bayer image.

The source is a seeded smooth + textured image over the whole 12-bit range, with the
four Bayer channels at different levels (so a site put in the wrong place, or a gamma
table applied to the wrong channel, shows as a large error). It is read out with each
FLIPH/FLIPV combination, encoded as the camera would, and decoded; the result must be
the flipped source within the 8-bit code's own resolution.

The code step at a level comes from the ENCODER's table (the range of 16-bit samples the
camera maps to one code), not from the decoder:
- "the JPEG's own rounding": the decoded value lies at most one code step (the distance
  to a neighbouring code's centre) from the centre of the code the camera produced;
- against the source, that adds the code's own half step; the median error is under
  half a step (most pixels keep their code at quality 100).
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from elphel_host.camera.jp4 import decode_jp4
from elphel_sim.jp4 import code_lut, encode_jp4, gamma_table

T0 = 1_700_000_000_123_456_000
FLIPPED_BAYER = {(0, 0): "GRBG", (1, 0): "RGGB", (0, 1): "BGGR", (1, 1): "GBRG"}
# The decoder rounds its output to whole DN; the table's piecewise-linear inverse can sit
# a DN or two off the exact bin centre where a bin spans a table knot.
DN = 2.0


def source_image(h: int = 128, w: int = 256, seed: int = 7) -> NDArray[np.uint16]:
    """Sensor-native (G R / B G) 12-bit mosaic: smooth + texture, channels at distinct levels."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w]).reshape(2, 1, 1)
    base = 0.5 + 0.5 * np.sin(2 * np.pi * (1.3 * x + 0.4 * y)) * np.cos(2 * np.pi * 0.7 * y)
    value = np.clip(base + rng.normal(0.0, 0.04, (h, w)), 0.0, 1.0)
    level = np.tile(np.array([[0.8, 1.0], [0.45, 0.8]]), (h // 2, w // 2))  # G R / B G
    return np.round(value * level * 4095).astype(np.uint16)


def code_bins(gamma: float, black: float) -> tuple[NDArray[np.uint8], NDArray[np.float64], ...]:
    """The camera's code of every 16-bit sample, and per code its step and centre (output DN)."""
    lut = code_lut(gamma_table(gamma, black, 0x400))
    v = np.arange(65536)
    lo = np.full(256, 65536.0)
    hi = np.zeros(256)
    np.minimum.at(lo, lut, v)
    np.maximum.at(hi, lut, v + 1)
    used = hi > 0
    step = np.where(used, hi - lo, 0.0) / 65536 * 65535
    centre = np.where(used, np.clip(((lo + hi) / 2 / 65536 - black) * 65535, 0, None), np.nan)
    # distance to the nearest used neighbour's centre on either side: one code step
    idx = np.flatnonzero(used)
    gaps = np.diff(centre[idx])
    neighbour = np.zeros(256)
    neighbour[idx[:-1]] = gaps
    neighbour[idx[1:]] = np.maximum(neighbour[idx[1:]], gaps)
    return lut, step, centre, neighbour


def readout(mosaic: NDArray[np.uint16], fliph: int, flipv: int) -> NDArray[np.uint16]:
    out = mosaic[:, ::-1] if fliph else mosaic
    return np.ascontiguousarray(out[::-1] if flipv else out)


def linear(mosaic: NDArray[np.uint16], black: float) -> NDArray[np.float64]:
    """The source as the decoder should return it: fraction of full scale x 65535, black off."""
    return np.clip((mosaic * 16.0 / 65536 - black) * 65535, 0, None)


CASES = [
    (mode, gamma, black, flips)
    for mode in (5, 2)
    for gamma in (1.0, 0.57)
    for black in (0.0, 10 / 256)
    for flips in ((0, 0), (1, 0), (0, 1), (1, 1))
]


def _ids(case: tuple) -> str:
    mode, gamma, black, flips = case
    return f"{'jp4' if mode == 5 else 'jp46'}-g{gamma}-b{round(black * 256)}-f{flips[0]}{flips[1]}"


@pytest.mark.parametrize("case", CASES, ids=[_ids(c) for c in CASES])
def test_quality_100_within_one_code_step(case: tuple) -> None:
    mode, gamma, black, flips = case
    read = readout(source_image(), *flips)
    data = encode_jp4(
        read, bits=12, frame=77, timestamp_ns=T0, color_mode=mode, quality=100,
        gamma=gamma, black=black, flips=flips,
    )  # fmt: skip
    image, meta = decode_jp4(data)
    assert image.dtype == np.uint16 and image.shape == read.shape
    assert meta["bayer"] == FLIPPED_BAYER[flips]
    assert (meta["FLIPH"], meta["FLIPV"], meta["COLOR"]) == (*flips, mode)
    assert meta["source"] == ("jp4" if mode == 5 else "jp46")

    lut, step, centre, neighbour = code_bins(gamma, black)
    code = lut[read.astype(np.int64) * 16]
    got = image.astype(np.float64)
    # the JPEG's own rounding: at most one code step from the camera's code
    jpeg_error = np.abs(got - centre[code])
    assert np.all(jpeg_error <= neighbour[code] + DN), float((jpeg_error - neighbour[code]).max())
    # against the source: the code's own half step on top of that
    error = np.abs(got - linear(read, black))
    assert np.all(error <= step[code] / 2 + neighbour[code] + DN)
    assert np.median(error / step[code]) < 0.5
    # and the decoded image is the flipped source, in no other orientation
    for other in FLIPPED_BAYER:
        if other != flips:
            wrong = np.abs(got - linear(readout(source_image(), *other), black))
            assert np.median(wrong / step[code]) > 5, other


@pytest.mark.parametrize("case", CASES, ids=[_ids(c) for c in CASES])
def test_quality_90_bayer_order(case: tuple) -> None:
    """At quality 90 too the order is exactly right: the flipped source, no other orientation."""
    mode, gamma, black, flips = case
    source = source_image()
    read = readout(source, *flips)
    data = encode_jp4(
        read, bits=12, frame=77, timestamp_ns=T0, color_mode=mode, quality=90,
        gamma=gamma, black=black, flips=flips,
    )  # fmt: skip
    image, meta = decode_jp4(data)
    assert meta["bayer"] == FLIPPED_BAYER[flips] and meta["quality"] == 90
    lut, step, _, _ = code_bins(gamma, black)
    code = lut[read.astype(np.int64) * 16]
    right = np.median(np.abs(image - linear(read, black)) / step[code])
    assert right < 3.0
    for other in FLIPPED_BAYER:
        if other != flips:
            wrong = np.abs(image - linear(readout(source, *other), black)) / step[code]
            assert np.median(wrong) > 3 * right, other


@pytest.mark.parametrize("mode", [5, 2])
@pytest.mark.parametrize("gamma", [1.0, 0.57])
def test_quality_90_figures(mode: int, gamma: float, capsys: pytest.CaptureFixture) -> None:
    """Quality 90: the figures docs/formats.md states (median ~2.3 code steps on this image)."""
    read = source_image()
    data = encode_jp4(read, bits=12, frame=1, timestamp_ns=T0, color_mode=mode, quality=90,
                      gamma=gamma)  # fmt: skip
    image, meta = decode_jp4(data)
    assert meta["quality"] == 90
    lut, step, _, _ = code_bins(gamma, 0.0)
    code = lut[read.astype(np.int64) * 16]
    error = np.abs(image - linear(read, 0.0))
    in_steps = error / step[code]
    rms = float(np.sqrt(np.mean(error**2)))
    with capsys.disabled():
        print(
            f"\nq90 {'jp4' if mode == 5 else 'jp46'} gamma {gamma}: median "
            f"{np.median(in_steps):.2f} steps, p99 {np.percentile(in_steps, 99):.1f}, "
            f"max {in_steps.max():.1f}, rms {rms:.0f} DN of 65535"
        )
    assert np.median(in_steps) < 3.0
    assert rms < 0.02 * 65535


def test_per_channel_gamma_goes_to_the_right_sites() -> None:
    """Four different gammas: a table applied at the wrong site gives a large error."""
    gammas = (0.4, 0.7, 1.0, 1.3)  # R, Gr, Gb, B
    for flips in FLIPPED_BAYER:
        for bayer_mode in range(4):
            read = readout(source_image(64, 128), *flips)
            data = encode_jp4(read, bits=12, frame=1, timestamp_ns=T0, gamma=gammas,
                              flips=flips, bayer_mode=bayer_mode)  # fmt: skip
            image, meta = decode_jp4(data)
            assert meta["gamma"] == list(gammas)
            assert meta["BAYER"] == bayer_mode
            error = np.abs(image - linear(read, 0.0))
            assert np.percentile(error, 99) < 0.02 * 65535, (flips, bayer_mode)


@pytest.mark.parametrize(
    ("bayer_mode", "expected"), [(0, "GRBG"), (1, "RGGB"), (2, "BGGR"), (3, "GBRG")]
)
def test_bayer_mode_shifts_the_pattern(bayer_mode: int, expected: str) -> None:
    data = encode_jp4(np.zeros((16, 32), np.uint16), bits=12, frame=1, timestamp_ns=T0,
                      bayer_mode=bayer_mode)  # fmt: skip
    assert decode_jp4(data)[1]["bayer"] == expected


def test_mono_jpeg_and_metadata() -> None:
    read = source_image(48, 80)
    data = encode_jp4(
        read, bits=12, frame=4242, timestamp_ns=T0 + 999_000, port=3, exposure_us=12345,
        color_mode=0, quality=100, gains=(0x10000, 0x18000, 0x20000, 0x28000),
        woi=(8, 16, 80, 48), decimation=(2, 2), binning=(1, 2),
    )  # fmt: skip
    image, meta = decode_jp4(data)
    error = np.abs(image - linear(read, 0.0))
    assert error.max() <= 1.5 * 256 * 65535 / 65536 + DN  # gamma 1: a code is 256 DN
    assert meta == {
        "frame": 4242,
        "timestamp_ns": T0 + 999_000,
        "port": 3,
        "bayer": None,
        "EXPOS": 12345,
        "GAINR": 0x10000,
        "GAING": 0x18000,
        "GAINGB": 0x20000,
        "GAINB": 0x28000,
        "WOI_LEFT": 8,
        "WOI_TOP": 16,
        "WOI_WIDTH": 80,
        "WOI_HEIGHT": 48,
        "FLIPH": 0,
        "FLIPV": 0,
        "BAYER": 0,
        "DCM_HOR": 2,
        "DCM_VERT": 2,
        "BIN_HOR": 1,
        "BIN_VERT": 2,
        "COLOR": 0,
        "source": "jpeg",
        "gamma": [1.0] * 4,
        "black_level": [0.0] * 4,
        "gamma_scale": [0x400] * 4,
        "quality": 100,
        "full_scale_dn": 65535,
    }


def test_gamma_scale_is_undone() -> None:
    read = source_image(32, 64) // 2  # half range, so a 2x table scale does not clip
    data = encode_jp4(read, bits=12, frame=1, timestamp_ns=T0, gamma_scale=0x800)
    image, meta = decode_jp4(data)
    assert meta["gamma_scale"] == [0x800] * 4
    assert np.abs(image - linear(read, 0.0)).max() <= 1.5 * 128 * 65535 / 65536 + DN
