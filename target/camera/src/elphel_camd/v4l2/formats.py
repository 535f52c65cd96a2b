"""Raw V4L2 pixel formats: what each fourcc holds, how it is laid out, which one to stream.

A raw format is Bayer (one of four colour orders) or mono, 8/10/12/16 significant bits,
stored one of three ways: one byte a pixel, two bytes a pixel (little-endian, the value in
the low bits), or packed the CSI-2 way (RAW10: 4 pixels in 5 bytes; RAW12: 2 pixels in
3 bytes). Facts: the kernel's pixfmt-srggb10, -srggb10p and -srggb12p pages.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import Enum

BAYER_ORDERS = ("RGGB", "GRBG", "GBRG", "BGGR")


class Packing(Enum):
    """How the pixels of one line are laid out in bytes."""

    BYTE = "byte"  # one byte a pixel
    WORD = "word"  # two bytes a pixel, little-endian, value in the low bits
    CSI2 = "csi2"  # MIPI CSI-2 packing: RAW10 4 pixels in 5 bytes, RAW12 2 in 3


@dataclass(frozen=True)
class RawFormat:
    """One raw pixel format.

    Parameters
    ----------
    fourcc
        The four characters V4L2 names it by (``"pRAA"``, ``"RG10"``, ``"Y16 "``).
    bits
        Significant bits of a pixel.
    packing
        The byte layout of a line.
    bayer
        Colour order of the top-left 2x2 cell (``"RGGB"`` ...), None for mono.
    """

    fourcc: str
    bits: int
    packing: Packing
    bayer: str | None

    @property
    def code(self) -> int:
        """The 32-bit pixel format code V4L2 uses for this fourcc."""
        return fourcc_code(self.fourcc)

    def line_bytes(self, width: int) -> int:
        """Bytes of one line of ``width`` pixels without padding."""
        if self.packing is Packing.BYTE:
            return width
        if self.packing is Packing.WORD:
            return 2 * width
        return width * self.bits // 8

    @property
    def pixels_per_group(self) -> int:
        """Pixels in one packed group (4 for RAW10, 2 for RAW12, 1 unpacked)."""
        if self.packing is not Packing.CSI2:
            return 1
        return 4 if self.bits == 10 else 2


def fourcc_code(fourcc: str) -> int:
    """The 32-bit code of a four-character code (first character in the low byte)."""
    if len(fourcc) != 4:
        raise ValueError(f"fourcc {fourcc!r}: must be 4 characters")
    return sum(ord(c) << (8 * i) for i, c in enumerate(fourcc))


def fourcc_text(code: int) -> str:
    """The four characters of a 32-bit pixel format code."""
    return "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4))


def _table() -> dict[str, RawFormat]:
    bayer_fourccs = {
        (8, Packing.BYTE): ("RGGB", "GRBG", "GBRG", "BA81"),
        (10, Packing.WORD): ("RG10", "BA10", "GB10", "BG10"),
        (12, Packing.WORD): ("RG12", "BA12", "GB12", "BG12"),
        (16, Packing.WORD): ("RG16", "GR16", "GB16", "BYR2"),
        (10, Packing.CSI2): ("pRAA", "pgAA", "pGAA", "pBAA"),
        (12, Packing.CSI2): ("pRCC", "pgCC", "pGCC", "pBCC"),
    }
    mono_fourccs = {
        (8, Packing.BYTE): "GREY",
        (10, Packing.WORD): "Y10 ",
        (12, Packing.WORD): "Y12 ",
        (16, Packing.WORD): "Y16 ",
        (10, Packing.CSI2): "Y10P",
        (12, Packing.CSI2): "Y12P",
    }
    table: dict[str, RawFormat] = {}
    for (bits, packing), fourccs in bayer_fourccs.items():
        for order, fourcc in zip(BAYER_ORDERS, fourccs, strict=True):
            table[fourcc] = RawFormat(fourcc, bits, packing, order)
    for (bits, packing), fourcc in mono_fourccs.items():
        table[fourcc] = RawFormat(fourcc, bits, packing, None)
    return table


RAW_FORMATS: Mapping[str, RawFormat] = _table()
RAW_BY_CODE: Mapping[int, RawFormat] = {f.code: f for f in RAW_FORMATS.values()}


def raw_format(fourcc: str) -> RawFormat:
    """The raw format of a fourcc (ValueError naming the ones known)."""
    found = RAW_FORMATS.get(fourcc)
    if found is None:
        known = ", ".join(repr(f) for f in RAW_FORMATS)
        raise ValueError(f"pixel format {fourcc!r} is not a raw format; raw formats: {known}")
    return found


def flipped_bayer(order: str, *, hflip: bool, vflip: bool) -> str:
    """The colour order a Bayer sensor reads out with its mirror bits set.

    A horizontal flip swaps the two colours of each row, a vertical flip swaps the rows:
    RGGB becomes GRBG, GBRG and BGGR.
    """
    if order not in BAYER_ORDERS:
        raise ValueError(f"bayer order {order!r}; allowed: {', '.join(BAYER_ORDERS)}")
    top, bottom = order[:2], order[2:]
    if hflip:
        top, bottom = top[::-1], bottom[::-1]
    if vflip:
        top, bottom = bottom, top
    return top + bottom


@dataclass(frozen=True)
class FormatChoice:
    """A raw format and frame size to stream."""

    format: RawFormat
    width: int
    height: int


def choose_format(
    offered: Mapping[str, Iterable[tuple[int, int]]],
    *,
    current: tuple[str, int, int] | None = None,
    wanted_fourcc: str | None = None,
    wanted_size: tuple[int, int] | None = None,
) -> FormatChoice:
    """The raw format and size to stream from what a node offers.

    Parameters
    ----------
    offered
        Fourcc -> the frame sizes (width, height) the node offers in it.
    current
        The node's current (fourcc, width, height).
    wanted_fourcc, wanted_size
        What the configuration names, if anything.

    Returns
    -------
    FormatChoice
        The named format and size if given; else the current format if it is raw; else the
        raw format with the most bits at the largest size.

    Raises
    ------
    ValueError
        No raw format is offered (the message lists the offered ones), or a named format or
        size is not offered (the message lists what is).
    """
    raw = {f: list(sizes) for f, sizes in offered.items() if f in RAW_FORMATS}
    if not raw:
        listed = ", ".join(repr(f) for f in offered) or "none"
        raise ValueError(f"the node offers no raw Bayer or mono format; it offers: {listed}")
    if wanted_fourcc is not None:
        if wanted_fourcc not in raw:
            listed = ", ".join(repr(f) for f in raw)
            raise ValueError(f"format {wanted_fourcc!r} is not offered; raw formats: {listed}")
        fourcc = wanted_fourcc
    elif current is not None and current[0] in raw:
        fourcc = current[0]
    else:
        fourcc = max(raw, key=lambda f: (RAW_FORMATS[f].bits, max(_area(s) for s in raw[f])))
    return FormatChoice(RAW_FORMATS[fourcc], *_size(fourcc, raw[fourcc], current, wanted_size))


def _area(size: tuple[int, int]) -> int:
    return size[0] * size[1]


def _size(
    fourcc: str,
    sizes: list[tuple[int, int]],
    current: tuple[str, int, int] | None,
    wanted: tuple[int, int] | None,
) -> tuple[int, int]:
    if wanted is not None:
        if sizes and wanted not in sizes:
            listed = ", ".join(f"{w}x{h}" for w, h in sizes)
            raise ValueError(f"size {wanted[0]}x{wanted[1]} is not offered in {fourcc!r}: {listed}")
        return wanted
    if current is not None and current[0] == fourcc and (not sizes or current[1:] in sizes):
        return current[1], current[2]
    if not sizes:
        if current is None:
            raise ValueError(f"the node names no frame size for {fourcc!r}")
        return current[1], current[2]
    return max(sizes, key=_area)
