"""Simulated stage hardware: stepper + ball screw + carriage, limit switches, and the wiring.

The mechanics turn STEP pulses on the board's pins into carriage motion with backlash,
lead error, missed steps above a pulse rate, hard end stops and a stall fault.
`StageHardware` wires them and the caliper (`elphel_sim.caliper`) to the pins of the
simulated ESP8266. Every noise source takes a seed.
"""

from __future__ import annotations

import math
import random
import threading
from dataclasses import dataclass
from typing import Any

from elphel_sim.caliper import FORMAT_CLOCK, SimCaliper
from elphel_sim.micropython.esp8266 import SimEsp8266
from elphel_sim.micropython.pins import FunctionSignal


@dataclass
class MechanicsConfig:
    mm_per_step: float = 0.008778
    backlash_mm: float = 0.05
    travel_mm: float = 120.0
    start_mm: float = 40.0
    lead_error_mm: float = 0.004  # periodic lead error amplitude
    lead_period_mm: float = 5.0
    max_step_hz: float = 5000.0  # above this rate steps are missed
    lim_min_mm: float = 0.3  # switch closes at or below
    lim_max_mm: float = 119.7  # switch closes at or above


class StageMechanics:
    """Motor steps -> nut -> carriage, with backlash and lead error. Thread-safe reads."""

    def __init__(self, cfg: MechanicsConfig, *, seed: int = 0, world: Any = None) -> None:
        self.cfg = cfg
        self.rng = random.Random(seed)
        self.world = world
        self.lock = threading.Lock()
        # Motor angle in steps, measured from the hard min end stop.
        self.motor_steps = cfg.start_mm / cfg.mm_per_step
        self.carriage_mm = self._nut_mm(self.motor_steps)
        self.last_step_us: int | None = None
        self.stalled = False
        self.enabled = True
        self.dir_level = 0
        self.dir_positive = 1
        self.steps_taken = 0
        self.steps_missed = 0
        self.end_stop_hits = 0
        self.min_mm_seen = self.carriage_mm
        self.max_mm_seen = self.carriage_mm
        self._publish()

    def _nut_mm(self, motor_steps: float) -> float:
        x = motor_steps * self.cfg.mm_per_step
        return x + self.cfg.lead_error_mm * math.sin(2 * math.pi * x / self.cfg.lead_period_mm)

    def _publish(self) -> None:
        rig = getattr(self.world, "rig", None)
        if rig is not None and hasattr(rig, "carriage_mm"):
            rig.carriage_mm = float(self.carriage_mm)

    def step(self, t_us: int) -> None:
        """One STEP pulse (rising edge) at virtual time t_us."""
        with self.lock:
            rate_ok = True
            if self.last_step_us is not None:
                dt = t_us - self.last_step_us
                if dt > 0 and 1e6 / dt > self.cfg.max_step_hz:
                    excess = 1e6 / dt / self.cfg.max_step_hz - 1.0
                    rate_ok = self.rng.random() > min(1.0, 0.2 + 4 * excess)
            self.last_step_us = t_us
            if not self.enabled or self.stalled or not rate_ok:
                self.steps_missed += 1
                return
            d = 1 if self.dir_level == self.dir_positive else -1
            new_steps = self.motor_steps + d
            nut = self._nut_mm(new_steps)
            half = self.cfg.backlash_mm / 2
            c = self.carriage_mm
            if nut - c > half:
                c = nut - half
            elif c - nut > half:
                c = nut + half
            if c < 0.0 or c > self.cfg.travel_mm:
                self.end_stop_hits += 1  # the carriage is against a hard stop: motor slips
                self.steps_missed += 1
                return
            self.motor_steps = new_steps
            self.carriage_mm = c
            self.steps_taken += 1
            self.min_mm_seen = min(self.min_mm_seen, c)
            self.max_mm_seen = max(self.max_mm_seen, c)
        self._publish()

    def lim_min(self) -> bool:
        return self.carriage_mm <= self.cfg.lim_min_mm

    def lim_max(self) -> bool:
        return self.carriage_mm >= self.cfg.lim_max_mm


class StageHardware:
    """Wires mechanics and caliper to a SimEsp8266's GPIO, as the firmware config names them."""

    def __init__(
        self,
        board: SimEsp8266,
        mech: StageMechanics,
        caliper: SimCaliper,
        pins: dict[str, int],
        *,
        limit_active: int = 0,
        enable_active: int = 0,
        dir_positive: int = 1,
    ) -> None:
        self.board = board
        self.mech = mech
        self.caliper = caliper
        mech.dir_positive = dir_positive
        bank = board.pins

        def pressed(fn: Any) -> Any:
            return lambda: limit_active if fn() else 1 - limit_active

        bank.attach_input(pins["lim_min"], FunctionSignal(pressed(mech.lim_min)))
        bank.attach_input(pins["lim_max"], FunctionSignal(pressed(mech.lim_max)))

        def on_step(level: int, t_us: int) -> None:
            if level:
                mech.step(t_us)

        def on_dir(level: int, t_us: int) -> None:
            mech.dir_level = level

        def on_enable(level: int, t_us: int) -> None:
            mech.enabled = level == enable_active

        bank.listen(pins["step"], on_step)
        bank.listen(pins["dir"], on_dir)
        bank.listen(pins["enable"], on_enable)
        clock_kind = FORMAT_CLOCK[caliper.cfg.fmt]

        class _Clk:
            def level_at(self, t_us: int) -> int:
                return caliper.clk_at(t_us)

            def next_change(self, t_us: int) -> int | None:
                return caliper.next_change(t_us)

        class _Data:
            def level_at(self, t_us: int) -> int:
                return caliper.data_at(t_us)

            def next_change(self, t_us: int) -> int | None:
                return caliper.next_change(t_us) if clock_kind != "host" else None

        if clock_kind == "host":
            bank.listen(pins["cal_clk"], caliper.on_host_clock)
        else:
            bank.attach_input(pins["cal_clk"], _Clk())
        bank.attach_input(pins["cal_data"], _Data())
        bank.listen(pins["cal_zero"], caliper.on_zero_line)
        bank.listen(pins["cal_power"], caliper.on_power)
