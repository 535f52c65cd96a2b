"""The compressor's parameters of one port, frame by frame."""

from elphel_sim.stock.compressor import ELPHEL_GAMMA, CompressorSchedule


def test_changes_take_effect_from_their_frame_and_invalid_ones_are_dropped():
    c = CompressorSchedule(raw_only=False)
    assert c.state_at(0) == {
        "COLOR": 5,
        "QUALITY": 100,
        **dict.fromkeys(("GTAB_R", "GTAB_G", "GTAB_GB", "GTAB_B"), ELPHEL_GAMMA),
    }
    assert c.set(10, {"COLOR": 15, "QUALITY": 0, "GTAB_R": 0x00640400}) == {
        "COLOR": 15,
        "GTAB_R": 0x00640400,
    }
    assert c.set(12, {"COLOR": 7, "GTAB_G": 0x000C0400}) == {}  # JP4DIFF; gamma 0.12
    assert [c.state_at(f)["COLOR"] for f in (9, 10, 11)] == [5, 15, 15]
    assert c.state_at(10)["QUALITY"] == 100
    # Long after, the old changes are folded into the base and still in effect.
    assert c.state_at(10_000)["GTAB_R"] == 0x00640400


def test_the_lepton_stays_raw():
    c = CompressorSchedule(raw_only=True)
    assert c.set(3, {"COLOR": 5}) == {}
    assert c.state_at(5)["COLOR"] == 15
