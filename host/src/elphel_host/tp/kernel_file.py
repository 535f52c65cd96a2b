"""A quad's aberration-correction kernel file: its ``quad.json`` entry and its array."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError

F32 = NDArray[np.float32]

#: Largest ``kernels.target_sigma_px`` accepted (sensor px).
MAX_TARGET_SIGMA_PX = 5.0


@dataclass(frozen=True)
class KernelFile:
    """``"kernels": {"file": "kernels.npy", "step": 16}``: aberration kernels of the quad.

    The file holds a NumPy array ``(4, colours, ky, kx, 15, 15)``: a grid of pixel-domain
    convolution kernels ``step`` pixels apart (see docs/tile-processor.md).
    ``target_sigma_px``, when known, is the Gaussian (sensor px) every kernel turns its
    cell's point-spread function into: with it the PSFs can be recovered from the kernels
    (``elphel mfsr --psf quad=DIR``); the tile processor does not need it.
    """

    file: str
    step: int = 16
    target_sigma_px: float | None = None

    def to_json(self) -> dict[str, Any]:
        """The ``kernels`` entry of ``quad.json``."""
        out: dict[str, Any] = {"file": self.file, "step": self.step}
        if self.target_sigma_px is not None:
            out["target_sigma_px"] = self.target_sigma_px
        return out


def kernel_file(spec: Any, source: str) -> KernelFile | None:
    """The ``kernels`` entry of a quad.json (``source`` names it in errors), checked."""
    if spec is None:
        return None
    if not isinstance(spec, dict) or "file" not in spec:
        raise InputFormatError(
            f"{source}: kernels={spec!r}; allowed: {{'file': NAME.npy, 'step': 16}}"
        )
    step = spec.get("step", 16)
    if not isinstance(step, int) or step < 1:
        raise InputFormatError(f"{source}: kernels.step={step!r}; allowed: an integer >= 1")
    target = spec.get("target_sigma_px")
    if target is not None and not (
        isinstance(target, int | float) and 0 < target <= MAX_TARGET_SIGMA_PX
    ):
        raise InputFormatError(
            f"{source}: kernels.target_sigma_px={target!r}; allowed: a number of sensor px "
            f"> 0 and <= {MAX_TARGET_SIGMA_PX}"
        )
    return KernelFile(
        file=str(spec["file"]),
        step=step,
        target_sigma_px=None if target is None else float(target),
    )


def load_kernels(file: Path, source: Path) -> F32:
    """The kernel array named by the quad.json ``source`` (its shape checked by the user)."""
    if not file.is_file():
        raise InputFormatError(f"{source}: kernels.file {file} does not exist")
    try:
        data = np.load(file, allow_pickle=False)
    except ValueError as e:
        raise InputFormatError(f"{file}: not a .npy array ({e})") from e
    return np.asarray(data, dtype=np.float32)
