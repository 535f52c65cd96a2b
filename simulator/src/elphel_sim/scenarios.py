"""Named scenes and rigs for the simulator (``elphel-sim up --scenario NAME``)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from types import ModuleType
from typing import Any

from elphel_camd.sensors import imx219_registers, mt9f002
from elphel_camd.sensors import mt9p006 as spec
from elphel_sim.calib_board import CalibScene, CalibView, calib_scene
from elphel_sim.chips.lepton35 import lepton_intrinsics
from elphel_sim.quad import QuadRig, QuadScene, standard_scene
from elphel_sim.relief import relief_scene
from elphel_sim.render import Intrinsics, LensBlur, SensorModel
from elphel_sim.world import CameraMount, Plane, Rig, Scene, Texture, World


@dataclass(frozen=True)
class PortSpec:
    """A sensor port of the simulated board: which chip, which camera, which mount.

    ``lens_blur``: the lens's blur on the Aptina sensors' images; the scenarios' default
    renders a perfectly sharp lens. ``calib``: the port sees the world's calibration
    board through its own lens (`elphel_sim.calib_board`) instead of the scene's planes.
    """

    model: str | None
    mount: str
    intrinsics: Intrinsics
    sensor: SensorModel = field(default_factory=SensorModel)
    lens_blur: LensBlur = field(default_factory=LensBlur)
    calib: CalibView | None = None

    def forming_options(self) -> dict[str, Any]:
        """`SimSensor.form_image`'s keyword arguments from this port (the noise aside)."""
        options: dict[str, Any] = {
            "intrinsics": self.intrinsics,
            "model": self.sensor,
            "lens_blur": self.lens_blur,
        }
        if self.calib is not None:
            options["calib"] = self.calib
        return options


@dataclass
class Scenario:
    """A world and the board's ports; ``quad`` when ports 0..3 form a quad camera.

    ``calib``: ports 0..3 are a calibration rig looking at a printed board.

    ``daemon_per_port``: each camera is a board of its own with its own daemon (a rig of
    Raspberry Pis), rather than a port of one multi-sensor board.
    """

    world: World
    ports: list[PortSpec]
    quad: QuadScene | None = None
    daemon_per_port: bool = False
    calib: CalibScene | None = None


# A well-lit lab scene: radiance 0.5 fills half the well in about 10 ms at gain 1.
LAB_LIGHT = SensorModel(bits=12, electrons_per_us=0.8, full_well_e=8000.0, dn_per_e=0.5)


def full_array(
    sensor: ModuleType,
    focal_length_mm: float,
    centre: tuple[float, float],
    *,
    pixel_pitch_um: float | None = None,
) -> Intrinsics:
    """A sensor's full pixel array behind a lens, the optical centre at ``centre`` (array px).

    ``sensor`` is the daemon's sensor module (its ``ARRAY_WIDTH``, ``ARRAY_HEIGHT`` and
    ``PIXEL_PITCH_UM``); ``pixel_pitch_um`` overrides the pitch.
    """
    return Intrinsics(
        focal_length_mm=focal_length_mm,
        pixel_pitch_um=sensor.PIXEL_PITCH_UM if pixel_pitch_um is None else pixel_pitch_um,
        width=sensor.ARRAY_WIDTH,
        height=sensor.ARRAY_HEIGHT,
        cx=centre[0],
        cy=centre[1],
    )


def mt9p006_intrinsics(focal_length_mm: float) -> Intrinsics:
    """The MT9P006's full pixel array with the optical centre on the default window's centre."""
    return full_array(
        spec, focal_length_mm, (16 + spec.ACTIVE_WIDTH / 2, 54 + spec.ACTIVE_HEIGHT / 2)
    )


def tilted_mount(name: str, tilt_deg: float) -> CameraMount:
    """A camera rolled about its optical axis so that the stage axis crosses its rows.

    With tan(tilt) = 1/S a single linear stage samples S x S sub-pixel phases (a burst plan
    recommends the tilt).
    """
    t = math.radians(tilt_deg)
    x_axis = (math.cos(t), math.sin(t), 0.0)
    y_axis = (-math.sin(t), math.cos(t), 0.0)
    return CameraMount(name, rotation=(x_axis, y_axis, (0.0, 0.0, 1.0)))


def default(seed: int) -> Scenario:
    """The burst rig: an MT9P006 on the stage carriage, 1 m in front of a textured wall.

    The camera is rolled by atan(1/4), the tilt `elphel burst plan --bayer` asks for at
    x2 (its Bayer sensor samples each colour every 2 px), and the wall's texture has detail
    down to about 1.6 px, finer than the sensor resolves alone.
    """
    wall = Plane(
        Texture.procedural(period_mm=400.0, seed=seed, size=2048, band=0.5),
        origin=(0.0, 0.0, 1000.0),
        albedo_rgb=(0.9, 1.0, 0.8),
    )
    mount = tilted_mount("cam0", math.degrees(math.atan(1 / 4)))
    world = World(Scene([wall]), Rig(axis=(1.0, 0.0, 0.0), mounts={"cam0": mount}))
    return Scenario(world, [PortSpec("MT9P006", "cam0", mt9p006_intrinsics(4.5), LAB_LIGHT)])


def mt9f002_intrinsics(focal_length_mm: float) -> Intrinsics:
    """The MT9F002's full pixel array with the optical centre on the default window's centre."""
    centre = (
        mt9f002.CLEAR_LEFT + mt9f002.IMAGE_WIDTH / 2,
        mt9f002.CLEAR_TOP + mt9f002.IMAGE_HEIGHT / 2,
    )
    return full_array(mt9f002, focal_length_mm, centre)


def mixed(seed: int) -> Scenario:
    """Three sensor models side by side, 1 m in front of a textured wall.

    Port 0 an MT9P006, port 1 an MT9F002, port 2 a Lepton 3.5 (whose image maps the
    wall's radiance to temperature); port 3 is empty.
    """
    wall = Plane(
        Texture.procedural(period_mm=1500.0, seed=seed, size=2048, band=0.5),
        origin=(0.0, 0.0, 1000.0),
        albedo_rgb=(0.9, 1.0, 0.8),
    )
    mounts = {f"cam{i}": CameraMount(f"cam{i}", offset_mm=(40.0 * i, 0.0, 0.0)) for i in range(3)}
    world = World(Scene([wall]), Rig(axis=(1.0, 0.0, 0.0), mounts=mounts))
    return Scenario(
        world,
        [
            PortSpec("MT9P006", "cam0", mt9p006_intrinsics(4.5), LAB_LIGHT),
            PortSpec("MT9F002", "cam1", mt9f002_intrinsics(4.5), LAB_LIGHT),
            PortSpec("LEPTON35", "cam2", lepton_intrinsics()),
            PortSpec(None, "cam0", mt9p006_intrinsics(4.5)),
        ],
    )


# Elphel's quad: 4.5 mm lenses on MT9P006 sensors, 150 mm apart (the square's side).
QUAD_RIG = QuadRig(
    width=spec.ACTIVE_WIDTH,
    height=spec.ACTIVE_HEIGHT,
    focal_length_mm=4.5,
    pixel_pitch_um=spec.PIXEL_PITCH_UM,
    baseline_mm=150.0,
    bayer=spec.BAYER,
)


def quad_intrinsics(rig: QuadRig) -> Intrinsics:
    """The MT9P006 array with the optical centre exactly on the default window's centre.

    The default window starts at Elphel's clear-area origin, so the window's pixel (x, y)
    is the quad rig's pixel (x, y) and tile truth needs no offset.
    """
    centre = (spec.CLEAR_LEFT + rig.width / 2, spec.CLEAR_TOP + rig.height / 2)
    return full_array(spec, rig.focal_length_mm, centre, pixel_pitch_um=rig.pixel_pitch_um)


def quad(seed: int) -> Scenario:
    """A quad camera: four MT9P006 on ports 0..3 at the corners of a 150 mm square.

    Port i is camera i of the Elphel square (the quad directory's positions (-0.5, -0.5),
    (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5) of the side, +x right, +y down), all looking
    along +z with parallel axes. They see the tile processor's standard scene
    (`elphel_sim.quad.standard_scene`): a background at disparity 0, fronto-parallel
    rectangles at 0.37, 2.5 and 5.2 px (59 m to 830 m away with this rig), a slanted
    and a texture-less rectangle. Share one trigger (TRIG=4 on every port, TRIG_PERIOD
    on the master) and the four frames of a trigger are one quad set.
    """
    rig = QUAD_RIG
    scene = standard_scene(rig, seed=seed)
    mounts = {
        f"cam{i}": CameraMount(
            f"cam{i}", offset_mm=(rig.baseline_mm * x, rig.baseline_mm * y, 0.0), on_stage=False
        )
        for i, (x, y) in enumerate(rig.positions)
    }
    world = World(scene.scene, Rig(axis=(1.0, 0.0, 0.0), mounts=mounts))
    intrinsics = quad_intrinsics(rig)
    ports = [PortSpec("MT9P006", f"cam{i}", intrinsics, LAB_LIGHT) for i in range(4)]
    return Scenario(world, ports, quad=scene)


#: The stage axis of the quad rig, tilted in the image plane so that one linear axis
#: samples sub-pixel phases along both image axes (tan = 1/4, as the burst plan asks at x2
#: with a Bayer sensor); the quad itself stays square and upright.
QUAD_RIG_AXIS_DEG = math.degrees(math.atan(1 / 4))


def quad_rig(seed: int) -> Scenario:
    """The quad camera on the stage carriage, in front of the relief scene.

    Four MT9P006 on ports 0..3 at the corners of a 150 mm square (as ``quad``), mounted on
    the carriage, whose axis runs at atan(1/4) to the image rows; the scene is
    `elphel_sim.relief.relief_scene`: a back wall at disparity 1 px (307 m), three steps
    at 4.2, 4.8 and 5.4 px, a slanted plane from 1.5 to 3.5 px and a cylinder whose front
    is at 3.5 px, textured up to 1 cycle/px. A stage step of s mm shifts a surface of
    disparity D by D * s / 150 px along the axis.
    """
    return _quad_on_carriage(QUAD_RIG, seed)


#: The small relief view of `quad_rig_small`: the centre of the quad's view.
SMALL_VIEW = (640, 480)


def quad_rig_small(seed: int) -> Scenario:
    """`quad_rig` with the whole relief scene in the centre 640x480 of the view.

    The same cameras, optics and carriage; the relief scene is laid out for a 640x480
    sensor on the same optical axis, so a centred 640x480 window (``GET {sim_url}/quad``
    gives it as ``window``) sees all of it, and a burst of small frames is quick to take:
    for trying `elphel burst capture --quad` and `elphel depth` (and for ``make demo``).
    """
    width, height = SMALL_VIEW
    # The optical axis meets the default window at (width/2, height/2) of QUAD_RIG.
    window = {
        "WOI_LEFT": (QUAD_RIG.width - width) // 2,
        "WOI_TOP": (QUAD_RIG.height - height) // 2,
        "WOI_WIDTH": width,
        "WOI_HEIGHT": height,
    }
    view = replace(QUAD_RIG, width=width, height=height)
    return _quad_on_carriage(QUAD_RIG, seed, view=view, window=window)


def _quad_on_carriage(
    rig: QuadRig,
    seed: int,
    *,
    view: QuadRig | None = None,
    window: dict[str, int] | None = None,
) -> Scenario:
    """Cameras of ``rig`` on the carriage; the relief scene laid out for ``view`` (or rig)."""
    scene = relief_scene(view or rig, seed=seed)
    scene.window = window
    mounts = {
        f"cam{i}": CameraMount(
            f"cam{i}", offset_mm=(rig.baseline_mm * x, rig.baseline_mm * y, 0.0), on_stage=True
        )
        for i, (x, y) in enumerate(rig.positions)
    }
    t = math.radians(QUAD_RIG_AXIS_DEG)
    world = World(scene.scene, Rig(axis=(math.cos(t), math.sin(t), 0.0), mounts=mounts))
    intrinsics = quad_intrinsics(rig)
    ports = [PortSpec("MT9P006", f"cam{i}", intrinsics, LAB_LIGHT) for i in range(4)]
    return Scenario(world, ports, quad=scene)


# The IMX219's 1.12 um pixels in the same light: half their well (4500 e-) in 10 ms at
# radiance 0.5, 10-bit output (simulation values, not sensor facts).
PI_LIGHT = SensorModel(
    bits=imx219_registers.BITS,
    electrons_per_us=0.45,
    full_well_e=4500.0,
    dn_per_e=1023 / 4500,
    read_noise_e=2.5,
)
# The dissertation's rig: two Raspberry Pi cameras v2 on the carriage (calibration.md 2).
PI_PAIR_BASELINE_MM = 89.98
PI_PAIR_FOCAL_LENGTH_MM = 3.04
PI_PAIR_DISTANCE_MM = 300.0


def imx219_intrinsics(focal_length_mm: float) -> Intrinsics:
    """The IMX219's native array with the optical centre on the active area's centre."""
    r = imx219_registers
    centre = (r.ACTIVE_LEFT + r.ACTIVE_WIDTH / 2, r.ACTIVE_TOP + r.ACTIVE_HEIGHT / 2)
    return full_array(r, focal_length_mm, centre)


def pi_pair(seed: int) -> Scenario:
    """The dissertation's rig: two IMX219 side by side on the stage carriage.

    Camera 0 (port 0) and camera 1 (port 1) sit 89.98 mm apart along the stage axis
    behind 3.04 mm lenses, 300 mm in front of a textured wall whose detail reaches about
    1.6 px, finer than the sensors resolve alone. Each is rolled by atan(1/4), the tilt
    `elphel burst plan --bayer` asks for at x2, so one linear axis samples the sub-pixel
    phases of both. `elphel-sim up` serves each camera by its own daemon, as each Pi runs
    its own.
    """
    wall = Plane(
        Texture.procedural(period_mm=180.0, seed=seed, size=2048, band=0.5),
        origin=(0.0, 0.0, PI_PAIR_DISTANCE_MM),
        albedo_rgb=(0.9, 1.0, 0.8),
    )
    tilt_deg = math.degrees(math.atan(1 / 4))
    mounts = {
        name: replace(tilted_mount(name, tilt_deg), offset_mm=(x_mm, 0.0, 0.0))
        for name, x_mm in (("cam0", 0.0), ("cam1", PI_PAIR_BASELINE_MM))
    }
    world = World(Scene([wall]), Rig(axis=(1.0, 0.0, 0.0), mounts=mounts))
    intrinsics = imx219_intrinsics(PI_PAIR_FOCAL_LENGTH_MM)
    ports = [PortSpec("IMX219", name, intrinsics, PI_LIGHT) for name in mounts]
    return Scenario(world, ports, daemon_per_port=True)


#: The lens image of `calib_small`: the centre of the MT9P006's active area.
CALIB_SMALL_VIEW = (640, 480)
_ACTIVE = (spec.ACTIVE_WIDTH, spec.ACTIVE_HEIGHT)
_CLEAR = (spec.CLEAR_LEFT, spec.CLEAR_TOP)


def calib(seed: int) -> Scenario:
    """A quad calibration rig looking at a printed checkerboard (docs/calibration.md).

    Four MT9P006 on ports 0..3 at the corners of a 150 mm square, each behind its own
    lens (`elphel_sim.calib_rig.make_rig`: OpenCV's rational model, a 1 % spread of focal
    lengths, about 0.4 degrees of rotation, a blur of 0.7 px at the centre to 1.1 px in
    the corners) over the default 2592x1944 window. A 9x6 board of 25 mm squares
    (10 x 7 squares) is posed through ``{sim_url}/board``; the board is out of view
    until then.
    """
    return _calib(calib_scene(*_ACTIVE, active=_ACTIVE, clear=_CLEAR, seed=seed))


def calib_small(seed: int) -> Scenario:
    """`calib` with 640x480 cameras: the lenses describe a centred 640x480 window.

    Set that window (``GET {sim_url}/board`` gives it as ``window``, WOI_* parameters) on
    every port before capturing: frames are then small and quick to form, for tests and
    for trying `elphel calibrate capture`.
    """
    width, height = CALIB_SMALL_VIEW
    return _calib(calib_scene(width, height, active=_ACTIVE, clear=_CLEAR, seed=seed))


def _calib(scene: CalibScene) -> Scenario:
    """Ports 0..3 seeing ``scene``'s board through the rig's cameras 0..3."""
    mounts = {
        f"cam{i}": CameraMount(f"cam{i}", offset_mm=tuple(-cam.R.T @ cam.t_mm), on_stage=False)
        for i, cam in enumerate(scene.rig.cameras)
    }
    world = World(Scene([]), Rig(axis=(1.0, 0.0, 0.0), mounts=mounts))
    intrinsics = mt9p006_intrinsics(4.5)  # the array (the lenses are the rig's own)
    ports = [
        PortSpec("MT9P006", f"cam{i}", intrinsics, LAB_LIGHT, calib=scene.view(i))
        for i in range(len(scene.rig.cameras))
    ]
    return Scenario(world, ports, calib=scene)


SCENARIOS: dict[str, Callable[[int], Scenario]] = {"default": default}
SCENARIOS["mixed"] = mixed
SCENARIOS["quad"] = quad
SCENARIOS["quad-rig"] = quad_rig
SCENARIOS["quad-rig-small"] = quad_rig_small
SCENARIOS["pi-pair"] = pi_pair
SCENARIOS["calib"] = calib
SCENARIOS["calib-small"] = calib_small


def build(name: str, *, seed: int, lens_blur: LensBlur | None = None) -> Scenario:
    """Scenario ``name``; ``lens_blur`` puts that lens blur on every port."""
    try:
        factory = SCENARIOS[name]
    except KeyError:
        raise ValueError(f"scenario {name!r}; allowed: {', '.join(sorted(SCENARIOS))}") from None
    scenario = factory(seed)
    if lens_blur is not None:
        scenario.ports = [replace(p, lens_blur=lens_blur) for p in scenario.ports]
    return scenario
