"""Named scenes and rigs for the simulator (``elphel-sim up --scenario NAME``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from elphel_camd.sensors import mt9p006 as spec
from elphel_sim.render import Intrinsics, SensorModel
from elphel_sim.world import CameraMount, Plane, Rig, Scene, Texture, World


@dataclass(frozen=True)
class PortSpec:
    """A sensor port of the simulated board: which chip, which camera, which mount."""

    model: str | None
    mount: str
    intrinsics: Intrinsics
    sensor: SensorModel = field(default_factory=SensorModel)


@dataclass
class Scenario:
    world: World
    ports: list[PortSpec]


# A well-lit lab scene: radiance 0.5 fills half the well in about 10 ms at gain 1.
LAB_LIGHT = SensorModel(bits=12, electrons_per_us=0.8, full_well_e=8000.0, dn_per_e=0.5)


def mt9p006_intrinsics(focal_length_mm: float) -> Intrinsics:
    """The MT9P006's full pixel array with the optical centre on the default window's centre."""
    return Intrinsics(
        focal_length_mm=focal_length_mm,
        pixel_pitch_um=spec.PIXEL_PITCH_UM,
        width=spec.ARRAY_WIDTH,
        height=spec.ARRAY_HEIGHT,
        cx=16 + spec.ACTIVE_WIDTH / 2,
        cy=54 + spec.ACTIVE_HEIGHT / 2,
    )


def default(seed: int) -> Scenario:
    """One MT9P006 on the stage carriage, 1 m in front of a textured wall."""
    wall = Plane(
        Texture.procedural(period_mm=1500.0, seed=seed, size=2048, band=0.5),
        origin=(0.0, 0.0, 1000.0),
        albedo_rgb=(0.9, 1.0, 0.8),
    )
    world = World(Scene([wall]), Rig(axis=(1.0, 0.0, 0.0), mounts={"cam0": CameraMount("cam0")}))
    return Scenario(world, [PortSpec("MT9P006", "cam0", mt9p006_intrinsics(4.5), LAB_LIGHT)])


SCENARIOS: dict[str, Callable[[int], Scenario]] = {"default": default}


def build(name: str, *, seed: int) -> Scenario:
    try:
        factory = SCENARIOS[name]
    except KeyError:
        raise ValueError(f"scenario {name!r}; allowed: {', '.join(sorted(SCENARIOS))}") from None
    return factory(seed)
