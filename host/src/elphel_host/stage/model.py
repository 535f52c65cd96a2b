"""The stage model: steps to caliper millimetres, and the calibration kept between commands.

``mm = offset_mm + steps * mm_per_step`` for a carriage that arrived moving towards
+steps (approaching from the other side adds ``backlash_mm``). `StageModel.save` and
`StageModel.load` keep it in a JSON file (``elphel stage ... --model PATH``) so a later
command moves in the calibrated frame; `elphel_host.stage.positioning` measures it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from elphel_host import strict_json
from elphel_host.errors import InputFormatError, StageNotHomedError
from elphel_host.fileio import write_atomic
from elphel_host.stage.client import NOMINAL_MM_PER_STEP


@dataclass
class StageModel:
    mm_per_step: float = NOMINAL_MM_PER_STEP
    offset_mm: float | None = None
    backlash_mm: float = 0.0
    calibrated: bool = False
    spread_mm_per_step: float = math.nan
    readings: list[tuple[int, float]] = field(default_factory=list)

    @classmethod
    def load(cls, path: Path) -> StageModel:
        """A calibration saved by `save` (a default model if the file does not exist)."""
        if not path.exists():
            return cls()
        try:
            data = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise InputFormatError(f"{path}: not valid JSON ({e})") from e
        if not isinstance(data, dict):
            raise InputFormatError(f"{path}: top level={type(data).__name__}; allowed: an object")

        def number(key: str, value: object, *, positive: bool = False) -> float:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
            if ok and positive:
                ok = math.isfinite(float(value)) and float(value) > 0  # type: ignore[arg-type]
            if not ok:
                allowed = "a number > 0" if positive else "a number"
                raise InputFormatError(f"{path}: {key}={value!r}; allowed: {allowed}")
            return float(value)  # type: ignore[arg-type]

        offset = data.get("offset_mm")
        return cls(
            mm_per_step=number("mm_per_step", data.get("mm_per_step"), positive=True),
            offset_mm=None if offset is None else number("offset_mm", offset),
            backlash_mm=number("backlash_mm", data.get("backlash_mm", 0.0)),
            calibrated=True,
            spread_mm_per_step=number(
                "spread_mm_per_step", data.get("spread_mm_per_step", math.nan)
            ),
        )

    def save(self, path: Path) -> None:
        """Keep the calibration for later commands (elphel stage ... --model PATH)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        data = {
            "mm_per_step": self.mm_per_step,
            "offset_mm": self.offset_mm,
            "backlash_mm": self.backlash_mm,
            "spread_mm_per_step": self.spread_mm_per_step,
        }
        text = strict_json.dumps(data, what=str(path), indent=1)
        write_atomic(path, text.encode())

    def steps_for(self, mm: float) -> float:
        if self.offset_mm is None:
            raise StageNotHomedError(
                "no caliper reference yet: read the caliper at a known step first"
            )
        return (mm - self.offset_mm) / self.mm_per_step

    def mm_at(self, steps: int) -> float:
        if self.offset_mm is None:
            raise StageNotHomedError("no caliper reference yet")
        return self.offset_mm + steps * self.mm_per_step
