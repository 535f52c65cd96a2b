"""Raw pixel formats: the fourcc table, Bayer orders under flips, and which format streams."""

from __future__ import annotations

import pytest

from elphel_camd.v4l2.formats import (
    RAW_BY_CODE,
    Packing,
    choose_format,
    flipped_bayer,
    fourcc_code,
    fourcc_text,
    raw_format,
)


def test_fourcc_codes_are_the_kernels() -> None:
    # V4L2_PIX_FMT_SRGGB10P = v4l2_fourcc('p', 'R', 'A', 'A')
    assert fourcc_code("pRAA") == ord("p") | ord("R") << 8 | ord("A") << 16 | ord("A") << 24
    assert fourcc_text(fourcc_code("BYR2")) == "BYR2"
    assert RAW_BY_CODE[fourcc_code("BA10")].bayer == "GRBG"


@pytest.mark.parametrize(
    ("fourcc", "bits", "packing", "bayer", "line_bytes"),
    [
        ("BA81", 8, Packing.BYTE, "BGGR", 3280),
        ("RG10", 10, Packing.WORD, "RGGB", 6560),
        ("GR16", 16, Packing.WORD, "GRBG", 6560),
        ("pBAA", 10, Packing.CSI2, "BGGR", 4100),
        ("pgCC", 12, Packing.CSI2, "GRBG", 4920),
        ("Y10P", 10, Packing.CSI2, None, 4100),
        ("Y16 ", 16, Packing.WORD, None, 6560),
    ],
)
def test_table_entries(
    fourcc: str, bits: int, packing: Packing, bayer: str | None, line_bytes: int
) -> None:
    fmt = raw_format(fourcc)
    assert (fmt.bits, fmt.packing, fmt.bayer) == (bits, packing, bayer)
    assert fmt.line_bytes(3280) == line_bytes


def test_a_non_raw_fourcc_is_refused_naming_the_raw_ones() -> None:
    with pytest.raises(ValueError, match=r"'YUYV' is not a raw format; raw formats: .*'pRAA'"):
        raw_format("YUYV")


@pytest.mark.parametrize(
    ("hflip", "vflip", "order"),
    [(False, False, "RGGB"), (True, False, "GRBG"), (False, True, "GBRG"), (True, True, "BGGR")],
)
def test_flips_of_rggb_give_the_orders_of_the_imx219(hflip: bool, vflip: bool, order: str) -> None:
    assert flipped_bayer("RGGB", hflip=hflip, vflip=vflip) == order
    assert flipped_bayer(order, hflip=hflip, vflip=vflip) == "RGGB"  # flips undo themselves


def test_the_current_raw_format_and_size_are_kept() -> None:
    offered = {"RG16": [(640, 480)], "BA10": [(640, 480), (1280, 720)]}
    got = choose_format(offered, current=("BA10", 640, 480))
    assert (got.format.fourcc, got.width, got.height) == ("BA10", 640, 480)


def test_without_a_raw_current_format_the_most_bits_at_the_largest_size_win() -> None:
    offered = {"YUYV": [(1920, 1080)], "BA10": [(1920, 1080)], "RG16": [(320, 240), (640, 480)]}
    got = choose_format(offered, current=("YUYV", 1920, 1080))
    assert (got.format.fourcc, got.width, got.height) == ("RG16", 640, 480)


def test_a_named_format_and_size_are_taken_or_refused_listing_what_is_offered() -> None:
    offered = {"RG10": [(640, 480), (1280, 720)], "RG12": [(640, 480)]}
    got = choose_format(offered, wanted_fourcc="RG12", wanted_size=(640, 480))
    assert (got.format.fourcc, got.width, got.height) == ("RG12", 640, 480)
    with pytest.raises(ValueError, match="'pRAA' is not offered; raw formats: 'RG10', 'RG12'"):
        choose_format(offered, wanted_fourcc="pRAA")
    with pytest.raises(
        ValueError, match="size 800x600 is not offered in 'RG10': 640x480, 1280x720"
    ):
        choose_format(offered, wanted_fourcc="RG10", wanted_size=(800, 600))


def test_a_node_without_raw_formats_is_refused_listing_its_formats() -> None:
    with pytest.raises(
        ValueError, match="offers no raw Bayer or mono format; it offers: 'YUYV', 'MJPG'"
    ):
        choose_format({"YUYV": [(640, 480)], "MJPG": [(640, 480)]})
