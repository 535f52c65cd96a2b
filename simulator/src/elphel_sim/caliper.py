"""The simulated caliper: frames of the true carriage position on its clock and data pins.

The simulator's own encoders of every format the firmware decodes (written from the
format facts, not from the firmware's decoder), and `SimCaliper`, which clocks those
frames out as pin levels in virtual time (device-clocked, host-clocked or on request),
with noise, power, zero line and glitch faults. Every noise source takes a seed.
"""

from __future__ import annotations

import bisect
import random
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from elphel_sim.stage_hw import StageMechanics

INCH_MM = 25.4


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
        return _sylvac48_frame(value_mm, sign_mode=sign_mode, negative_zero=negative_zero), 48
    if fmt == "bcd7":
        return _bcd7_frame(value_mm, inch=inch, negative=neg), 28
    if fmt == "igaging21":
        counts = round(value_mm / INCH_MM * 2560)
        return counts & ((1 << 21) - 1), 21
    if fmt == "digimatic":
        return _digimatic_frame(value_mm, inch=inch, negative=neg), 52
    raise ValueError(f"caliper format {fmt!r} unknown")


def _sylvac48_frame(value_mm: float, *, sign_mode: str, negative_zero: bool) -> int:
    """Two 24-bit words: counts since power-on, then the negated display value."""
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
    return w1 | (w2 << 24)


def _bcd7_frame(value_mm: float, *, inch: bool, negative: bool) -> int:
    """Six BCD digits LSD first, then the sign, half-digit and unit flags."""
    if inch:
        halves = round(abs(value_mm) / INCH_MM * 2000)
        digits, half = divmod(halves, 2)
    else:
        digits, half = round(abs(value_mm) * 100), 0
    frame = 0
    for i in range(6):
        frame |= ((digits // 10**i) % 10) << (4 * i)
    frame |= (1 << 24) if negative else 0
    frame |= (1 << 25) if half else 0
    frame |= 0 if inch else (1 << 27)
    return frame


def _digimatic_frame(value_mm: float, *, inch: bool, negative: bool) -> int:
    """13 nibbles: header 0xF x4, sign, six digits MSD first, decimal point, unit."""
    if inch:
        digits, point, unit = round(abs(value_mm) / INCH_MM * 100000), 5, 1
    else:
        digits, point, unit = round(abs(value_mm) * 1000), 3, 0
    nibbles = [0xF] * 4 + [8 if negative else 0]
    nibbles += [(digits // 10**i) % 10 for i in range(5, -1, -1)]
    nibbles += [point, unit]
    frame = 0
    for i, n in enumerate(nibbles):
        frame |= n << (4 * i)
    return frame


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
