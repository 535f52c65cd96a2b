"""Frame parameters: Elphel's names and units, validation, and what each one reprograms.

A port's parameters are one dictionary ``{name: int}``. Writable parameters are checked
against their limits — fixed ones from `PARAMS`, sensor-dependent ones from the driver —
and a set of changes is applied all-or-nothing. Each parameter names the program
functions it triggers (Elphel's onchange functions); a function's latency decides how many
frames before the target frame its register writes must be issued.

Facts: shared/reference/sensors.md sections 3.4 and 3.5.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from elphel_camd.errors import ParameterRangeError

# Program functions, in execution order (a subset of Elphel's onchange list).
WINDOW = "window"
EXPOSURE = "exposure"
GAINS = "gains"
TRIGGERMODE = "triggermode"
LIMITFPS = "limitfps"
TRIGSEQ = "trigseq"
FUNCTIONS = (TRIGGERMODE, WINDOW, GAINS, LIMITFPS, EXPOSURE, TRIGSEQ)

# TRIG values: 0 free-run, 4 snapshot (external/internal trigger, ERS), 20 snapshot + GRR.
TRIG_FREE_RUN = 0
TRIG_SNAPSHOT = 4
TRIG_SNAPSHOT_GRR = 20
TRIG_VALUES = (TRIG_FREE_RUN, TRIG_SNAPSHOT, TRIG_SNAPSHOT_GRR)

# TRIG_PERIOD: 0 stops the trigger, 1 = a single trigger; 2..255 are reserved.
TRIG_PERIOD_MIN_REPEAT = 256

# Parameters the board keeps common to all ports; the TRIG_MASTER port programs them.
COMMON_TRIGGER_PARAMS = ("TRIG_PERIOD",)
PORTS_MAX = 4


@dataclass(frozen=True)
class ParamSpec:
    """One frame parameter.

    Parameters
    ----------
    name
        Elphel's name.
    unit
        Unit of the value, as the REST API documents it.
    minimum, maximum
        Fixed limits; the driver may narrow them (see `SensorDriver.limits`).
    functions
        Program functions a change triggers.
    read_only
        Computed by the daemon; writing it is an error.
    doc
        Meaning.
    """

    name: str
    unit: str
    minimum: int
    maximum: int
    functions: tuple[str, ...] = ()
    read_only: bool = False
    doc: str = ""


_WIN = (WINDOW, EXPOSURE, LIMITFPS)

PARAMS: dict[str, ParamSpec] = {
    p.name: p
    for p in (
        ParamSpec("WOI_LEFT", "pixels", 0, 0xFFFF, _WIN, doc="window left edge (even)"),
        ParamSpec("WOI_TOP", "pixels", 0, 0xFFFF, _WIN, doc="window top edge (even)"),
        ParamSpec("WOI_WIDTH", "pixels", 2, 0xFFFF, _WIN, doc="window width (even)"),
        ParamSpec(
            "WOI_HEIGHT",
            "pixels",
            2,
            16384,
            _WIN,
            doc="window height (even); in photo-finish the composite frame's height",
        ),
        ParamSpec(
            "BIN_HOR",
            "factor",
            1,
            2,
            _WIN,
            doc="horizontal binning: 1 none, 2 two same-colour pixels become one "
            "(the frame is WOI_WIDTH / 2 wide)",
        ),
        ParamSpec(
            "BIN_VERT",
            "factor",
            1,
            2,
            _WIN,
            doc="vertical binning: 1 none, 2 two same-colour rows become one "
            "(the frame is WOI_HEIGHT / 2 high)",
        ),
        ParamSpec("FLIPH", "bit", 0, 1, _WIN, doc="mirror horizontally"),
        ParamSpec("FLIPV", "bit", 0, 1, _WIN, doc="mirror vertically"),
        ParamSpec("EXPOS", "us", 1, 0x7FFFFFFF, (EXPOSURE, LIMITFPS), doc="exposure time"),
        ParamSpec("VEXPOS", "rows", 1, 0xFFFFF, (EXPOSURE, LIMITFPS), doc="exposure in rows"),
        ParamSpec("GAINR", "16.16", 0x10000, 0xFC000, (GAINS,), doc="red gain, 0x10000 = 1.0"),
        ParamSpec("GAING", "16.16", 0x10000, 0xFC000, (GAINS,), doc="green (red rows) gain"),
        ParamSpec("GAINGB", "16.16", 0x10000, 0xFC000, (GAINS,), doc="green (blue rows) gain"),
        ParamSpec("GAINB", "16.16", 0x10000, 0xFC000, (GAINS,), doc="blue gain"),
        ParamSpec(
            "TRIG",
            "mode",
            0,
            TRIG_SNAPSHOT_GRR,
            (TRIGGERMODE, WINDOW, EXPOSURE, LIMITFPS, TRIGSEQ),
            doc="0 free-run, 4 snapshot (triggered), 20 snapshot with global reset release",
        ),
        ParamSpec(
            "TRIG_PERIOD",
            "10ns",
            0,
            0xFFFFFFFF,
            (TRIGSEQ, LIMITFPS),
            doc="common trigger period in 10 ns units: 0 stop, 1 single, >= 256 repeat",
        ),
        ParamSpec(
            "TRIG_MASTER",
            "port",
            0,
            PORTS_MAX - 1,
            (TRIGSEQ,),
            doc="port whose trigger settings program the common trigger",
        ),
        ParamSpec("TRIG_DELAY", "10ns", 0, 0xFFFFFFFF, (TRIGSEQ,), doc="this port's trigger delay"),
        ParamSpec(
            "TRIG_DECIMATE",
            "triggers",
            0,
            0xFFFF,
            (TRIGSEQ, LIMITFPS),
            doc="this port exposes on every (n+1)-th trigger",
        ),
        ParamSpec(
            "PF_HEIGHT",
            "rows",
            0,
            0xFFFF,
            (WINDOW, EXPOSURE, LIMITFPS),
            doc="photo-finish strip height (0 off, else even, >= 2)",
        ),
        ParamSpec(
            "FP1000SLIM", "fps*1000", 0, 0x7FFFFFFF, (LIMITFPS,), doc="frame-rate limit (0 = none)"
        ),
        ParamSpec(
            "FPSFLAGS",
            "bits",
            0,
            3,
            (LIMITFPS,),
            doc="bit 0 limit fps to FP1000SLIM, bit 1 keep fps (exposure cannot lengthen frames)",
        ),
        ParamSpec("COLOR", "code", 15, 15, read_only=True, doc="15 = raw 16-bit frames"),
        ParamSpec("BITS", "bits", 16, 16, read_only=True, doc="stored pixel depth (16)"),
        ParamSpec("FRAME", "frame", 0, 0x7FFFFFFF, read_only=True, doc="frame number"),
        ParamSpec("SENSOR", "code", 0, 0xFF, read_only=True, doc="sensor code (0x34 MT9P006 ...)"),
        ParamSpec("FP1000S", "fps*1000", 0, 0x7FFFFFFF, read_only=True, doc="actual frame rate"),
    )
}


def check_names(changes: Mapping[str, object]) -> None:
    """Reject unknown names, read-only names and non-integer values before anything else."""
    for name, value in changes.items():
        spec = PARAMS.get(name)
        if spec is None:
            raise ParameterRangeError(name, value, f"one of {', '.join(sorted(PARAMS))}")
        if spec.read_only:
            raise ParameterRangeError(name, value, "nothing: it is read-only")
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParameterRangeError(name, value, "an integer")


def functions_of(names: Iterable[str]) -> set[str]:
    """Program functions triggered by changing these parameters."""
    out: set[str] = set()
    for name in names:
        out.update(PARAMS[name].functions)
    return out


def check_range(name: str, value: int, minimum: int, maximum: int, *, even: bool = False) -> None:
    """Raise `ParameterRangeError` unless ``minimum <= value <= maximum`` (and even)."""
    if not minimum <= value <= maximum or (even and value % 2):
        allowed = f"{minimum}..{maximum}" + (" (even)" if even else "")
        raise ParameterRangeError(name, value, allowed)
