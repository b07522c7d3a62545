from __future__ import annotations

import pytest

from realitygap.robots.sensors import SensorMode, check_sensor_mode


def test_one_string_valued_enum_for_every_robot() -> None:
    assert [m.value for m in SensorMode] == ["image", "fast", "geometric"]
    both = (SensorMode.FAST, SensorMode.IMAGE)
    assert check_sensor_mode("fast", both) is SensorMode.FAST
    assert check_sensor_mode(SensorMode.IMAGE, both) is SensorMode.IMAGE
    assert check_sensor_mode("geometric", (SensorMode.GEOMETRIC,)) is SensorMode.GEOMETRIC
    with pytest.raises(ValueError, match=r"one of \['fast', 'image'\], got 'geometric'"):
        check_sensor_mode("geometric", both)
    with pytest.raises(ValueError, match="got 'photo'"):
        check_sensor_mode("photo", both)
