"""The simulated camera board: per port a simulated I2C bus with a chip, and an image path.

It implements the daemon's `Board` protocol, so the real daemon runs on it unchanged; the
daemon finds it as ``--board sim`` through the ``elphel_camd.boards`` entry point.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping

import numpy as np

from elphel_camd.board import Frame
from elphel_camd.errors import CaptureUnavailableError, PortError
from elphel_camd.i2c.bus import I2CBus
from elphel_sim.chips.bus import SimI2CBus
from elphel_sim.chips.mt9p006 import SimMT9P006
from elphel_sim.fpga import SensorTiming, mt9p006_frame
from elphel_sim.scenarios import PortSpec, Scenario, build


class SimBoard:
    """A simulated board serving a scenario's world.

    Parameters
    ----------
    scenario
        The world and the ports.
    seed
        Seed of the sensor noise (each port draws from its own stream).
    noise
        False renders the noise-free expectation (exact tests).
    """

    name = "sim"

    def __init__(self, scenario: Scenario, *, seed: int = 0, noise: bool = True) -> None:
        self.world = scenario.world
        self.ports: dict[int, PortSpec] = dict(enumerate(scenario.ports))
        self._buses: dict[int, SimI2CBus] = {}
        self.chips: dict[int, SimMT9P006] = {}
        self._frame = dict.fromkeys(self.ports, 0)
        self._time_s = dict.fromkeys(self.ports, 0.0)
        seeds = np.random.SeedSequence(seed).spawn(len(self.ports))
        self._rng = {
            port: np.random.default_rng(s) if noise else None
            for port, s in zip(self.ports, seeds, strict=True)
        }
        self._lock = threading.Lock()
        for port, spec in self.ports.items():
            bus = SimI2CBus(f"port {port}")
            if spec.model == "MT9P006":
                chip = SimMT9P006()
                bus.attach(chip.address, chip)
                self.chips[port] = chip
            elif spec.model is not None:
                raise ValueError(
                    f"port {port}: simulated sensor {spec.model!r}; allowed: MT9P006 or None"
                )
            self._buses[port] = bus

    def buses(self) -> Mapping[int, I2CBus]:
        return self._buses

    def bus(self, port: int) -> SimI2CBus:
        return self._buses[port]

    def capture(self, port: int) -> Frame:
        if port not in self.ports:
            raise PortError(f"port {port} does not exist; ports: {sorted(self.ports)}")
        chip = self.chips.get(port)
        if chip is None:
            raise CaptureUnavailableError(f"port {port}: no sensor on this simulated port")
        spec = self.ports[port]
        with self._lock:
            timing = SensorTiming(
                width=chip.peek("column_size") + 1,
                height=chip.peek("row_size") + 1,
                vertical_blank=chip.peek("vertical_blank"),
            )
            self._frame[port] += 1
            self._time_s[port] += timing.frame_s
            frame, time_s = self._frame[port], self._time_s[port]
            image = mt9p006_frame(
                chip,
                self.world,
                intrinsics=spec.intrinsics,
                mount=spec.mount,
                model=spec.sensor,
                rng=self._rng[port],
                time_s=time_s,
            )
        return Frame(image=image, frame=frame, timestamp_ns=round(time_s * 1e9))

    def close(self) -> None:
        """Nothing to release: the simulated buses hold no OS resources."""


def make_sim_board(*, scenario: str = "default", seed: int = 0, noise: bool = True) -> SimBoard:
    """Entry point for ``elphel-camd --board sim`` (options from ``--config``)."""
    return SimBoard(build(scenario, seed=seed), seed=seed, noise=noise)
