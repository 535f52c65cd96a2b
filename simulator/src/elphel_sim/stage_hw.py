"""Simulated stage hardware: stepper + ball screw + carriage, limit switches, caliper.

The mechanics turn STEP pulses on the board's pins into carriage motion with backlash,
lead error, missed steps above a pulse rate, hard end stops and a stall fault. The
caliper clocks out real frames of the true carriage position on its clock/data pins, in
any of the formats the firmware decodes. Every noise source takes a seed.
"""

from __future__ import annotations

import bisect
import math
import random
import threading
from dataclasses import dataclass, field
from typing import Any

from elphel_sim.micropython.board import SimBoard
from elphel_sim.micropython.pins import FunctionSignal

INCH_MM = 25.4


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


# ---- caliper frames (the simulator's own encoders, written from the format facts) ----


def _sm_field(count: int, mag_bits: int, sign_bit: int, negative: bool) -> int:
    mag = abs(count)
    if mag >= 1 << mag_bits:
        raise ValueError(f"count {count} does not fit {mag_bits} magnitude bits")
    return mag | ((1 << sign_bit) if negative else 0)


def encode_frame(
    fmt: str,
    value_mm: float,
    *,
    inch: bool = False,
    negative_zero: bool = False,
    sign_mode: str = "twos",
) -> tuple[int, int]:
    """Frame bits (bit 0 clocked first, start pulses not included) and their count.

    ``value_mm`` is what the caliper shows; the frame is quantised to the format's LSB.
    """
    neg = value_mm < 0 or negative_zero
    if fmt in ("bin6", "bin6_16"):
        count = round(abs(value_mm) / INCH_MM * 2000) if inch else round(abs(value_mm) * 100)
        mag_bits = 20 if fmt == "bin6" else 16
        frame = _sm_field(count, mag_bits, 20, neg and (count != 0 or negative_zero))
        return frame | ((1 << 23) if inch else 0), 24
    if fmt == "sylvac48":
        counts = round(value_mm / INCH_MM * 20480)
        word2 = -counts  # the second word carries the negated display value
        mask = (1 << 24) - 1
        if sign_mode == "ones":
            w2 = (~(-word2)) & mask if word2 < 0 else word2
            if negative_zero:
                w2 = mask
        elif sign_mode == "sm":
            w2 = _sm_field(word2, 23, 23, word2 < 0 or negative_zero)
        else:
            w2 = word2 & mask
        w1 = (counts + 123456) & mask  # absolute since power-on: unrelated offset
        return w1 | (w2 << 24), 48
    if fmt == "bcd7":
        if inch:
            halves = round(abs(value_mm) / INCH_MM * 2000)
            digits, half = divmod(halves, 2)
        else:
            digits, half = round(abs(value_mm) * 100), 0
        frame = 0
        for i in range(6):
            frame |= ((digits // 10**i) % 10) << (4 * i)
        frame |= (1 << 24) if neg else 0
        frame |= (1 << 25) if half else 0
        frame |= 0 if inch else (1 << 27)
        return frame, 28
    if fmt == "igaging21":
        counts = round(value_mm / INCH_MM * 2560)
        return counts & ((1 << 21) - 1), 21
    if fmt == "digimatic":
        if inch:
            digits, point, unit = round(abs(value_mm) / INCH_MM * 100000), 5, 1
        else:
            digits, point, unit = round(abs(value_mm) * 1000), 3, 0
        nibbles = [0xF] * 4 + [8 if neg else 0]
        nibbles += [(digits // 10**i) % 10 for i in range(5, -1, -1)]
        nibbles += [point, unit]
        frame = 0
        for i, n in enumerate(nibbles):
            frame |= n << (4 * i)
        return frame, 52
    raise ValueError(f"caliper format {fmt!r} unknown")


FORMAT_CLOCK = {
    "bin6": "device",
    "bin6_16": "device",
    "sylvac48": "device",
    "bcd7": "device",
    "igaging21": "host",
    "digimatic": "request",
}
FORMAT_START_PULSES = {"sylvac48": 1}


@dataclass
class CaliperConfig:
    fmt: str = "bin6"
    clk_idle: int = 1
    sample: str = "leave"  # data valid at the edge leaving idle ("return": the other)
    data_invert: int = 0
    period_us: int = 120_000  # frame period (about 8 frames/s)
    bit_us: int = 600  # clock period
    word_gap_us: int = 1_200  # the longer pause between 24-bit words (48-bit format)
    noise_mm: float = 0.002  # gaussian, before quantisation
    inch: bool = False
    sign_mode: str = "twos"  # 48-bit word sign convention
    zero_mm: float = 0.0  # true carriage position shown as 0
    extra: dict[str, Any] = field(default_factory=dict)


class SimCaliper:
    """Drives the caliper clock/data pins with frames of the true position."""

    def __init__(self, cfg: CaliperConfig, mech: StageMechanics, *, seed: int = 0) -> None:
        self.cfg = cfg
        self.mech = mech
        self.seed = seed
        self.rng = random.Random(seed)  # glitches
        self.powered = True
        self.glitches: list[str] = []
        self.frames_sent = 0
        self.glitches_sent = 0
        self._frame_index = -1
        self._times: list[int] = []
        self._clk: list[int] = []
        self._data: list[int] = []
        self._t0 = 0
        self.negative_zero = False
        # host-clocked state
        self._host_bits: list[int] = []
        self._host_index = 0
        self._host_level = cfg.data_invert
        self._host_last_edge = -(10**12)
        self._req_frame_at: int | None = None

    # -- pin signals --------------------------------------------------------------
    def shown_mm(self, t_us: int) -> float:
        """What the display shows for the frame that starts at virtual time t_us.

        The noise is drawn from (seed, t_us) rather than from one running generator, so a
        frame's value does not depend on how many frames were built before it (which
        follows the thread timing of the firmware's reads, not virtual time).
        """
        noise = random.Random(f"{self.seed}:{t_us}").gauss(0.0, self.cfg.noise_mm)
        return self.mech.carriage_mm - self.cfg.zero_mm + noise

    def _frame_bits(self, t_us: int) -> list[int]:
        frame, n = encode_frame(
            self.cfg.fmt,
            self.shown_mm(t_us),
            inch=self.cfg.inch,
            negative_zero=self.negative_zero,
            sign_mode=self.cfg.sign_mode,
        )
        bits = [1] * FORMAT_START_PULSES.get(self.cfg.fmt, 0) + [(frame >> i) & 1 for i in range(n)]
        self.frames_sent += 1
        if self.glitches:
            kind = self.glitches.pop(0)
            self.glitches_sent += 1
            if kind == "extra":
                bits.append(self.rng.getrandbits(1))
            elif kind == "short":
                bits = bits[: self.rng.randrange(1, len(bits) - 1)]
            else:  # "bits": flip a few random bits
                for _ in range(3):
                    i = self.rng.randrange(len(bits))
                    bits[i] ^= 1
        return bits

    def _build(self, t0: int, bits: list[int]) -> None:
        c = self.cfg
        idle, active = c.clk_idle, 1 - c.clk_idle
        p = c.bit_us
        times, clk, data = [], [], []
        t = t0
        for j, b in enumerate(bits):
            if j == 24 and c.fmt == "sylvac48":
                t += c.word_gap_us
            level = b ^ c.data_invert
            times.append(t - p // 4)
            clk.append(idle)
            data.append(level)
            times.append(t)
            clk.append(active)
            data.append(level)
            times.append(t + p // 2)
            clk.append(idle)
            data.append(level)
            t += p
        times.append(t)
        clk.append(idle)
        data.append(c.data_invert)
        self._times, self._clk, self._data = times, clk, data

    def _ensure_frame(self, t_us: int) -> None:
        if FORMAT_CLOCK[self.cfg.fmt] == "request":
            return
        k = (t_us + self.cfg.period_us // 2) // self.cfg.period_us
        if k != self._frame_index:
            self._frame_index = k
            self._t0 = k * self.cfg.period_us
            self._build(self._t0, self._frame_bits(self._t0) if self.powered else [])

    def _lookup(self, t_us: int, levels: list[int]) -> int:
        i = bisect.bisect_right(self._times, t_us) - 1
        if i < 0:
            return self.cfg.clk_idle if levels is self._clk else self.cfg.data_invert
        return levels[i]

    def clk_at(self, t_us: int) -> int:
        self._ensure_frame(t_us)
        return self._lookup(t_us, self._clk)

    def data_at(self, t_us: int) -> int:
        if FORMAT_CLOCK[self.cfg.fmt] == "host":
            return self._host_level
        self._ensure_frame(t_us)
        return self._lookup(t_us, self._data)

    def next_change(self, t_us: int) -> int | None:
        self._ensure_frame(t_us)
        i = bisect.bisect_right(self._times, t_us)
        if i < len(self._times):
            return self._times[i]
        if FORMAT_CLOCK[self.cfg.fmt] == "request":
            return None
        nxt = (self._frame_index + 1) * self.cfg.period_us
        return nxt - self.cfg.bit_us

    # -- firmware-driven lines ---------------------------------------------------------
    def on_host_clock(self, level: int, t_us: int) -> None:
        if not self.powered:
            return
        active = 1 - self.cfg.clk_idle
        if level == active:
            if t_us - self._host_last_edge > 2_000 or self._host_index >= len(self._host_bits):
                self._host_bits = self._frame_bits(t_us)
                self._host_index = 0
            b = self._host_bits[self._host_index] if self._host_index < len(self._host_bits) else 0
            self._host_index += 1
            self._host_level = b ^ self.cfg.data_invert
        self._host_last_edge = t_us

    def on_zero_line(self, level: int, t_us: int) -> None:
        if FORMAT_CLOCK[self.cfg.fmt] == "request":
            if level and self.powered:  # REQ: the gauge answers with one frame shortly after
                self._build(t_us + 500, self._frame_bits(t_us + 500))
            return
        if level:
            self.cfg.zero_mm = self.mech.carriage_mm

    def on_power(self, level: int, t_us: int) -> None:
        self.powered = bool(level)


class StageHardware:
    """Wires mechanics and caliper to a SimBoard's GPIO, as the firmware config names them."""

    def __init__(
        self,
        board: SimBoard,
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
