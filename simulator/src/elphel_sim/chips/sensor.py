"""What the simulated board's FPGA needs from a simulated sensor chip."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from numpy.typing import NDArray

from elphel_sim.render.optics import SHARP, LensBlur

if TYPE_CHECKING:
    from elphel_sim.calib_board import CalibView
    from elphel_sim.fpga import FrameRecord
    from elphel_sim.render import Intrinsics, SensorModel
    from elphel_sim.world import World


@dataclass(frozen=True)
class SensorTiming:
    """Frame timing of a sensor from its registers in effect.

    ``row_s`` is one row's duration, ``frame_rows`` the rows of a free-running frame
    (including blanking, and lengthened by a long exposure), ``exposure_rows`` the
    integration in rows and ``height`` the rows read out.
    """

    row_s: float
    frame_rows: int
    exposure_rows: int
    height: int

    @property
    def frame_s(self) -> float:
        return self.row_s * self.frame_rows

    @property
    def busy_s(self) -> float:
        """Shortest time from a trigger to the sensor being ready for the next one."""
        return self.row_s * (self.exposure_rows + self.height + 9)


@dataclass(frozen=True)
class ImageContext:
    """What forming a frame's image needs besides its record.

    The world seen, the port's camera intrinsics and sensor model, the noise generator
    (None: no noise) and the lens's blur (the Aptina sensors apply it, the Lepton's
    optics are its own). ``calib``: the port sees the world's calibration board through
    its own lens instead of the scene (the Aptina sensors).
    """

    world: World
    intrinsics: Intrinsics
    model: SensorModel
    rng: np.random.Generator | None
    lens_blur: LensBlur = SHARP
    calib: CalibView | None = None


class SimSensor(ABC):
    """A simulated sensor chip on a port: I2C device, frame latch, timing, image formation."""

    address: ClassVar[int]
    model: ClassVar[str]

    @abstractmethod
    def on_write(self, data: bytes) -> None: ...

    @abstractmethod
    def on_read(self, length: int) -> bytes: ...

    @abstractmethod
    def on_stop(self) -> None: ...

    @abstractmethod
    def latch(self, frame: int) -> None:
        """Frame ``frame`` starts: register writes due by now reach the image."""

    @abstractmethod
    def timing(self) -> SensorTiming: ...

    @abstractmethod
    def is_snapshot(self) -> bool:
        """Whether the sensor waits for a trigger to start a frame."""

    @abstractmethod
    def image_registers(self) -> dict[str, int]:
        """The register values shaping the current frame (recorded with the frame)."""

    def form_image(
        self,
        record: FrameRecord,
        world: World,
        *,
        intrinsics: Intrinsics,
        model: SensorModel,
        rng: np.random.Generator | None,
        lens_blur: LensBlur = SHARP,
        calib: CalibView | None = None,
    ) -> NDArray[np.uint16]:
        """The image of a recorded frame (from the record alone, not the chip's state)."""
        return self.render(record, ImageContext(world, intrinsics, model, rng, lens_blur, calib))

    @abstractmethod
    def render(self, record: FrameRecord, context: ImageContext) -> NDArray[np.uint16]:
        """The image of a recorded frame, from its registers."""
