"""The image shape of a V4L2 node (Elphel's WOI) and the two ways a driver lets it change.

A driver that crops (VIDIOC_S_SELECTION with V4L2_SEL_TGT_CROP succeeds) takes any window
inside its crop bounds: WOI_LEFT/TOP are the window's offset in the bounds and
WOI_WIDTH/HEIGHT its size, which is also the frame's. A driver that does not crop but
offers several discrete frame sizes (VIDIOC_ENUM_FRAMESIZES: a sensor's modes) takes
one of those sizes, set with VIDIOC_S_FMT; the mode decides where on the sensor it
reads, so WOI_LEFT/TOP are not offered. A driver with neither has a fixed shape. Either
change needs the stream stopped (the buffers change size): the board stops it, changes
the shape and starts it again between two frames.

Edges are even, so that a Bayer frame keeps its colour order.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from elphel_camd.errors import ControlRefusedError

WINDOW_PARAMS = ("WOI_LEFT", "WOI_TOP", "WOI_WIDTH", "WOI_HEIGHT")
SIZE_PARAMS = ("WOI_WIDTH", "WOI_HEIGHT")


@dataclass(frozen=True)
class Rect:
    """A rectangle in the driver's pixel coordinates."""

    left: int
    top: int
    width: int
    height: int


@dataclass(frozen=True)
class ShapeOptions:
    """How a node's shape can change.

    Parameters
    ----------
    crop_bounds
        The rectangle the driver's crop must stay inside (None: the driver does not crop).
    sizes
        The discrete frame sizes (width, height) the node offers in its format: its modes.
    """

    crop_bounds: Rect | None = None
    sizes: tuple[tuple[int, int], ...] = ()

    @property
    def kind(self) -> str:
        """``"crop"``, ``"modes"`` (two sizes or more, no crop) or ``"fixed"``."""
        if self.crop_bounds is not None:
            return "crop"
        return "modes" if len(self.sizes) > 1 else "fixed"

    @property
    def writable(self) -> frozenset[str]:
        """The window parameters this node can change."""
        return {
            "crop": frozenset(WINDOW_PARAMS),
            "modes": frozenset(SIZE_PARAMS),
            "fixed": frozenset(),
        }[self.kind]


@dataclass(frozen=True)
class Shape:
    """What the node is set to: its crop (when the driver crops) and its frame size."""

    crop: Rect | None
    size: tuple[int, int]


def sizes_text(sizes: tuple[tuple[int, int], ...]) -> str:
    return ", ".join(f"{w}x{h}" for w, h in sizes)


def _check_even(name: str, value: int, low: int, high: int, bounds: Rect) -> None:
    if not low <= value <= high or value % 2:
        raise ControlRefusedError(
            name,
            value,
            f"{low}..{high} (even), inside the driver's crop bounds {bounds.width}x{bounds.height}",
        )


def check_window(state: Mapping[str, int], options: ShapeOptions) -> None:
    """Raise ControlRefusedError unless the state's window is one the node can take."""
    if options.kind == "crop":
        b = options.crop_bounds
        assert b is not None
        width, height = state["WOI_WIDTH"], state["WOI_HEIGHT"]
        _check_even("WOI_WIDTH", width, 2, b.width, b)
        _check_even("WOI_HEIGHT", height, 2, b.height, b)
        _check_even("WOI_LEFT", state["WOI_LEFT"], 0, b.width - width, b)
        _check_even("WOI_TOP", state["WOI_TOP"], 0, b.height - height, b)
    elif options.kind == "modes":
        size = (state["WOI_WIDTH"], state["WOI_HEIGHT"])
        if size not in options.sizes:
            raise ControlRefusedError(
                "WOI_WIDTH",
                size[0],
                f"with WOI_HEIGHT={size[1]}, a size of one of the driver's modes: "
                f"{sizes_text(options.sizes)} (WOI_WIDTH and WOI_HEIGHT are set together; "
                "the mode decides the offset)",
            )


def wanted_shape(state: Mapping[str, int], options: ShapeOptions, current: Shape) -> Shape:
    """The shape a state's window asks of the node."""
    size = (state["WOI_WIDTH"], state["WOI_HEIGHT"])
    if options.kind == "crop":
        bounds = options.crop_bounds
        assert bounds is not None
        left, top = bounds.left + state["WOI_LEFT"], bounds.top + state["WOI_TOP"]
        return Shape(Rect(left, top, *size), size)
    if options.kind == "modes":
        return Shape(current.crop, size)
    return current


def window_params(shape: Shape, options: ShapeOptions) -> dict[str, int]:
    """WOI_* of a shape: the crop's offset in the bounds and the frame's size."""
    left = top = 0
    if shape.crop is not None and options.crop_bounds is not None:
        left = shape.crop.left - options.crop_bounds.left
        top = shape.crop.top - options.crop_bounds.top
    width, height = shape.size
    return {"WOI_LEFT": left, "WOI_TOP": top, "WOI_WIDTH": width, "WOI_HEIGHT": height}


def window_limits(state: Mapping[str, int], options: ShapeOptions) -> dict[str, tuple[int, int]]:
    """The range of each window parameter on this node in this state."""
    if options.kind == "crop":
        b = options.crop_bounds
        assert b is not None
        return {
            "WOI_WIDTH": (2, b.width),
            "WOI_HEIGHT": (2, b.height),
            "WOI_LEFT": (0, b.width - state["WOI_WIDTH"]),
            "WOI_TOP": (0, b.height - state["WOI_HEIGHT"]),
        }
    fixed = {name: (state[name], state[name]) for name in WINDOW_PARAMS}
    if options.kind == "modes":
        widths = [w for w, _ in options.sizes]
        heights = [h for _, h in options.sizes]
        fixed.update(WOI_WIDTH=(min(widths), max(widths)), WOI_HEIGHT=(min(heights), max(heights)))
    return fixed
