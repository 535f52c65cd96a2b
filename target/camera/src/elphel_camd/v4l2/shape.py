"""The image shape of a V4L2 node (Elphel's WOI) and the two ways a driver lets it change.

A driver that crops (VIDIOC_S_SELECTION with V4L2_SEL_TGT_CROP succeeds) takes any window
inside its crop bounds: WOI_LEFT/TOP are the window's offset in the bounds and
WOI_WIDTH/HEIGHT its size, which is also the frame's. A driver that does not crop but
offers several discrete frame sizes (VIDIOC_ENUM_FRAMESIZES: a sensor's modes) takes
one of those sizes, set with VIDIOC_S_FMT; the mode decides where on the sensor it
reads, so WOI_LEFT/TOP are not offered. A driver with neither has a fixed shape. Either
change needs the stream stopped (the buffers change size): the board stops it, changes
the shape and starts it again between two frames.

Some modes bin: the IMX219's mainline driver averages 2x2 same-colour pixels in its
1640x1232 and 640x480 modes (`BINNED_MODES`, by driver name). Such a mode is offered as
the window it reads on the sensor with BIN_HOR = BIN_VERT = 2: WOI_WIDTH x WOI_HEIGHT is
the mode's size times the binning (3280x2464 binned to 1640x1232), as the project's own
IMX219 driver counts it.

Edges are even, so that a Bayer frame keeps its colour order.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

from elphel_camd.errors import ControlRefusedError

WINDOW_PARAMS = ("WOI_LEFT", "WOI_TOP", "WOI_WIDTH", "WOI_HEIGHT")
SIZE_PARAMS = ("WOI_WIDTH", "WOI_HEIGHT")
BINNING_PARAMS = ("BIN_HOR", "BIN_VERT")
SHAPE_PARAMS = WINDOW_PARAMS + BINNING_PARAMS

# The modes of kernel drivers that bin, by driver name: frame size -> binning (both axes).
BINNED_MODES: Mapping[str, Mapping[tuple[int, int], int]] = {
    "imx219": {(1640, 1232): 2, (640, 480): 2},
}


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
    binned
        The sizes whose mode bins, with the binning (2: 2x2 pixels become one).
    """

    crop_bounds: Rect | None = None
    sizes: tuple[tuple[int, int], ...] = ()
    binned: tuple[tuple[tuple[int, int], int], ...] = ()

    def binning(self, size: tuple[int, int]) -> int:
        """The binning of the mode of a frame size (1 without)."""
        return dict(self.binned).get(size, 1)

    def windows(self) -> list[tuple[int, int, int]]:
        """Each mode as (WOI_WIDTH, WOI_HEIGHT, binning): the window it reads."""
        return [
            (w * self.binning((w, h)), h * self.binning((w, h)), self.binning((w, h)))
            for w, h in self.sizes
        ]

    @property
    def kind(self) -> str:
        """``"crop"``, ``"modes"`` (two sizes or more, no crop) or ``"fixed"``."""
        if self.crop_bounds is not None:
            return "crop"
        return "modes" if len(self.sizes) > 1 else "fixed"

    @property
    def writable(self) -> frozenset[str]:
        """The window and binning parameters this node can change."""
        if self.kind == "modes":
            return frozenset(SIZE_PARAMS + (BINNING_PARAMS if self.binned else ()))
        return frozenset(WINDOW_PARAMS) if self.kind == "crop" else frozenset()


def with_binned_modes(options: ShapeOptions, driver: str) -> ShapeOptions:
    """The options with the binned modes of a kernel driver (by name) that the node offers."""
    known = BINNED_MODES.get(driver.split()[0].lower() if driver else "", {})
    binned = tuple((size, factor) for size, factor in known.items() if size in options.sizes)
    return replace(options, binned=binned)


@dataclass(frozen=True)
class Shape:
    """What the node is set to: its crop (when the driver crops) and its frame size."""

    crop: Rect | None
    size: tuple[int, int]


def modes_text(options: ShapeOptions) -> str:
    """The modes as windows: ``3280x2464, 3280x2464 binned x2 (1640x1232), ...``."""
    return ", ".join(
        f"{w}x{h}" + (f" binned x{b} ({w // b}x{h // b})" if b > 1 else "")
        for w, h, b in options.windows()
    )


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
        binning = state.get("BIN_HOR", 1), state.get("BIN_VERT", 1)
        window = (state["WOI_WIDTH"], state["WOI_HEIGHT"], binning[0])
        if binning[0] != binning[1] or window not in options.windows():
            raise ControlRefusedError(
                "WOI_WIDTH",
                window[0],
                f"with WOI_HEIGHT={window[1]}, BIN_HOR={binning[0]}, BIN_VERT={binning[1]}: "
                f"the window of one of the driver's modes: {modes_text(options)} "
                "(WOI_WIDTH, WOI_HEIGHT and the binning are set together; the mode decides "
                "the offset)",
            )


def wanted_shape(state: Mapping[str, int], options: ShapeOptions, current: Shape) -> Shape:
    """The shape a state's window asks of the node."""
    size = (state["WOI_WIDTH"], state["WOI_HEIGHT"])
    if options.kind == "modes":
        size = (size[0] // state.get("BIN_HOR", 1), size[1] // state.get("BIN_VERT", 1))
    if options.kind == "crop":
        bounds = options.crop_bounds
        assert bounds is not None
        left, top = bounds.left + state["WOI_LEFT"], bounds.top + state["WOI_TOP"]
        return Shape(Rect(left, top, *size), size)
    if options.kind == "modes":
        return Shape(current.crop, size)
    return current


def window_params(shape: Shape, options: ShapeOptions) -> dict[str, int]:
    """WOI_* and BIN_* of a shape: the crop's offset, the window read, its binning."""
    left = top = 0
    if shape.crop is not None and options.crop_bounds is not None:
        left = shape.crop.left - options.crop_bounds.left
        top = shape.crop.top - options.crop_bounds.top
    width, height = shape.size
    binning = options.binning(shape.size) if options.kind == "modes" else 1
    return {
        "WOI_LEFT": left,
        "WOI_TOP": top,
        "WOI_WIDTH": width * binning,
        "WOI_HEIGHT": height * binning,
        "BIN_HOR": binning,
        "BIN_VERT": binning,
    }


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
            "BIN_HOR": (1, 1),
            "BIN_VERT": (1, 1),
        }
    fixed = {name: (state[name], state[name]) for name in SHAPE_PARAMS}
    if options.kind == "modes":
        windows = options.windows()
        widths, heights = [w for w, _, _ in windows], [h for _, h, _ in windows]
        most = max(b for _, _, b in windows)
        fixed.update(WOI_WIDTH=(min(widths), max(widths)), WOI_HEIGHT=(min(heights), max(heights)))
        fixed.update(BIN_HOR=(1, most), BIN_VERT=(1, most))
    return fixed
