"""The firmware's caliper reader decodes pin-level frames clocked out by the simulator."""

from __future__ import annotations

import pytest

from elphel_sim.caliper import CaliperConfig, SimCaliper
from elphel_sim.micropython.esp8266 import SimEsp8266
from elphel_sim.micropython.modules import FirmwareModules
from elphel_sim.stage_hw import MechanicsConfig, StageHardware, StageMechanics
from elphel_sim.stage_server import PINS

LSB_UM = {
    ("bin6", False): 10,
    ("bin6", True): 12.7,
    ("bin6_16", False): 10,
    ("sylvac48", False): 1.24,
    ("bcd7", False): 10,
    ("bcd7", True): 12.7,
    ("igaging21", False): 9.93,
    ("digimatic", False): 1,
    ("digimatic", True): 0.254,
}


class Rig:
    def __init__(self, tmp_path, cal: CaliperConfig, settings: dict | None = None) -> None:
        self.board = SimEsp8266(fs_dir=tmp_path, time_scale=1e9)
        self.mech = StageMechanics(MechanicsConfig(start_mm=50.0), seed=1)
        self.caliper = SimCaliper(cal, self.mech, seed=2)
        StageHardware(self.board, self.mech, self.caliper, PINS)
        mods = FirmwareModules(self.board)
        fake_machine = mods.fakes["machine"]
        fake_time = mods.fakes["time"]
        cfg_mod = mods._import("stage_config")
        reader_mod = mods._import("caliper_read")
        self.decode_mod = mods._import("caliper_decode")
        cal_cfg = dict(
            cfg_mod.DEFAULTS["caliper"],
            clk_idle=cal.clk_idle,
            sample=cal.sample,
            data_invert=cal.data_invert,
        )
        self.fmt = self.decode_mod.make_format(cal.fmt, settings or {})
        pin = fake_machine.Pin
        host = self.fmt["clock"] == "host"
        clk = pin(
            PINS["cal_clk"], pin.OUT if host else pin.IN, value=cal.clk_idle if host else None
        )
        self.reader = reader_mod.CaliperReader(
            cal_cfg,
            self.fmt,
            clk,
            pin(PINS["cal_data"], pin.IN),
            pin(PINS["cal_zero"], pin.OUT, value=0),
            pin(PINS["cal_power"], pin.OUT, value=1),
            fake_machine.time_pulse_us,
            fake_time.ticks_ms,
            fake_time.ticks_diff,
            fake_time.sleep_us,
            lambda: None,
        )
        self.error = reader_mod.CaliperError

    def show(self, shown_mm: float) -> None:
        self.mech.carriage_mm = 50.0
        self.caliper.cfg.zero_mm = 50.0 - shown_mm

    def close(self) -> None:
        self.board.close()


FORMATS = [
    ("bin6", False, {}),
    ("bin6", True, {}),
    ("bin6_16", False, {}),
    ("sylvac48", False, {"sign": "twos"}),
    ("sylvac48", False, {"sign": "ones"}),
    ("bcd7", False, {}),
    ("bcd7", True, {}),
    ("igaging21", False, {}),
    ("digimatic", False, {}),
    ("digimatic", True, {}),
]
VALUES_MM = [0.0, 0.01, 12.34, 100.0, -0.5, -12.34, -100.0]


@pytest.mark.parametrize(
    ("fmt", "inch", "settings"),
    FORMATS,
    ids=[f"{f}{'-inch' if i else ''}{'-' + s['sign'] if s else ''}" for f, i, s in FORMATS],
)
def test_every_format_decodes_from_pins(tmp_path, fmt, inch, settings):
    cal = CaliperConfig(fmt=fmt, inch=inch, noise_mm=0.0, sign_mode=settings.get("sign", "twos"))
    rig = Rig(tmp_path, cal, settings)
    try:
        values = [v for v in VALUES_MM if fmt != "bin6_16" or abs(v) < 600]
        for v in values:
            rig.show(v)
            um = rig.reader.read()
            assert abs(um - v * 1000) <= LSB_UM[(fmt, inch)] / 2 + 1, (fmt, inch, v, um)
    finally:
        rig.close()


NEG_ZERO = {
    "bin6": lambda f: f >> 20 & 1,
    "bcd7": lambda f: f >> 24 & 1,
    "digimatic": lambda f: (f >> 16 & 0xF) == 8,
    "sylvac48": lambda f: f >> 47 & 1,
}


@pytest.mark.parametrize(
    ("fmt", "settings"),
    [
        ("bin6", {}),
        ("bcd7", {}),
        ("digimatic", {}),
        ("sylvac48", {"sign": "ones"}),
        ("sylvac48", {"sign": "sm"}),
    ],
)
def test_negative_zero(tmp_path, fmt, settings):
    cal = CaliperConfig(fmt=fmt, noise_mm=0.0, sign_mode=settings.get("sign", "twos"))
    rig = Rig(tmp_path, cal, settings)
    try:
        rig.show(0.0)
        rig.caliper.negative_zero = True
        frame = rig.reader.read_frame()
        assert NEG_ZERO[fmt](frame), f"{fmt}: the simulated frame should carry the sign: {frame:#x}"
        assert rig.decode_mod.decode(rig.fmt, frame) == 0
        assert rig.reader.read() == 0
    finally:
        rig.close()


@pytest.mark.parametrize(
    ("idle", "sample", "invert"), [(1, "return", 0), (0, "leave", 1), (0, "return", 1)]
)
def test_clock_polarity_and_inverted_data(tmp_path, idle, sample, invert):
    rig = Rig(
        tmp_path, CaliperConfig(clk_idle=idle, sample=sample, data_invert=invert, noise_mm=0.0)
    )
    try:
        rig.show(-42.42)
        assert rig.reader.read() == -42420
    finally:
        rig.close()


@pytest.mark.parametrize("kind", ["bits", "extra", "short"])
def test_glitch_frames_are_never_reported(tmp_path, kind):
    rig = Rig(tmp_path, CaliperConfig(noise_mm=0.0))
    rejected = 0
    try:
        for i in range(40):
            v = 3.21 + i * 1.37
            rig.show(v)
            rig.caliper.glitches.extend([kind] * (1 + i % 2))
            try:
                um = rig.reader.read()
            except rig.error as e:
                assert e.code in (21, 22)
                rejected += 1
                continue
            assert abs(um - v * 1000) <= 10, (kind, v, um)
        assert rig.caliper.glitches_sent >= 40
        if kind != "bits":
            assert rejected + rig.caliper.glitches_sent >= 40
    finally:
        rig.close()


def test_no_frames_is_a_timeout_and_power_off_is_reported(tmp_path):
    rig = Rig(tmp_path, CaliperConfig(noise_mm=0.0))
    try:
        rig.caliper.powered = False
        with pytest.raises(rig.error, match=r"no caliper frame|caliper clock idle") as e:
            rig.reader.read()
        assert e.value.code == 20
        rig.reader.set_power(False)
        with pytest.raises(rig.error, match="power is off") as e:
            rig.reader.read()
        assert e.value.code == 23
    finally:
        rig.close()
