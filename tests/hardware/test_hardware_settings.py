"""Hardware settings: every bad value is named with its field (core, no pydrake)."""

from pcvfe_drake.hardware.settings import HardwareSettings, LcmBusSettings, hardware_problems


def test_defaults_are_valid_and_hold_zero_is_allowed():
    assert hardware_problems(HardwareSettings()) == []
    assert hardware_problems(HardwareSettings(playout_hold_s=0.0, first_message_timeout_s=0)) == []


def test_bad_values_are_named():
    bad = HardwareSettings(
        playout_hold_s=-0.1,
        state_timeout_s=0.0,
        lateness_clock="gps",
        bus="car",
        lcm_buses={"default": LcmBusSettings(lcm_url="localhost")},
    )
    text = "\n".join(hardware_problems(bad))
    for field in (
        "hardware.playout_hold_s=-0.1",
        "hardware.state_timeout_s=0.0",
        "hardware.lateness_clock='gps'",
        "hardware.bus='car'",
        "hardware.lcm_buses.default.lcm_url='localhost'",
    ):
        assert field in text, text
