"""The core's blocks, one step at a time, against hand-worked cases."""

import numpy as np
import pytest

from gripper_env.model.disturbances import CommandPath, Sensor
from gripper_env.sim.layout import P_REFRESH
from gripper_env.sim.mechanics import clamp_to_stops, count_contact
from gripper_env.sim.sensor import delay_line, sense
from gripper_env.sim.servo import servo_columns, servo_step


def _servo(us, params, state=(92.0, 0.0, 0.0, 0.0)):
    cmds = []
    for u in us:
        state = servo_step(u, state, params)
        cmds.append(state[0])
    return np.array(cmds), state


def test_servo_latches_whole_degrees_on_its_50_hz_ticks():
    assert servo_columns(CommandPath(refresh_period_s=0.02), 1e-3)[P_REFRESH] == 20
    # range 0-180 deg, 1-deg quantum, a tick every 20 steps, no rate limit
    us = [50.4] * 5 + [60.6] * 30 + [200.0] * 20
    cmds, (cmd, countdown, clip, tv) = _servo(us, (0.0, 180.0, 1.0, 20.0, 0.0))
    np.testing.assert_array_equal(cmds[:20], 50.0)  # latched at step 0, held through the change
    np.testing.assert_array_equal(cmds[20:40], 61.0)  # the next tick rounds 60.6 up
    np.testing.assert_array_equal(cmds[40:], 180.0)  # clipped to the range
    assert (cmd, countdown, clip) == (180.0, 5.0, 1.0)
    assert tv == pytest.approx(42.0 + 11.0 + 119.0)  # |50-92| + |61-50| + |180-61|


def test_servo_rate_limit_bounds_each_tick():
    # 100 deg/s at a 20-step tick of 1 ms: at most 2 deg per tick
    cmds, _ = _servo([100.0] * 60, (0.0, 180.0, 0.0, 20.0, 100.0 * 20 * 1e-3))
    np.testing.assert_allclose(cmds[[0, 20, 40]], [94.0, 96.0, 98.0])


def test_sensor_rounds_to_the_nearest_adc_count_and_delays():
    s = Sensor(adc_bits=10, adc_range_deg=(0.0, 270.0))
    lsb = s.lsb_deg
    params = (0, 0.0, lsb, 1.0 / lsb, 0.0, 1023.0)
    y, _ = sense(21.0, np.uint64(1), params)
    assert y == pytest.approx(80 * 270.0 / 1023)  # 21 / 0.2639 = 79.57 counts -> 80
    assert sense(-5.0, np.uint64(1), params)[0] == 0.0  # clipped to count 0
    buf = np.full((1, 4), 7.0)
    out, didx = [], 0
    for y_true in (1.0, 2.0, 3.0, 4.0, 5.0):
        y, didx = delay_line(y_true, 0, buf, didx, 2)
        out.append(y)
    assert out == [7.0, 7.0, 1.0, 2.0, 3.0]  # two steps late, the line's start value before


def test_a_jaw_held_at_a_stop_counts_contact_stall_and_force():
    params = (21.0, 95.0, 5.0, 1.0 / 5.0)  # stops 21 and 95 deg, stall band 5 deg
    assert count_contact(97.0, 105.0, (0.0, 0.0, 0.0), params) == (1.0, 1.0, 1.0)  # push 10
    assert count_contact(20.0, 19.0, (0.0, 0.0, 0.0), params) == (1.0, 0.0, 0.4)  # push 2
    assert count_contact(50.0, 105.0, (3.0, 2.0, 1.0), params) == (3.0, 2.0, 1.0)  # free
    assert [clamp_to_stops(x, params) for x in (97.0, 20.0, 50.0)] == [95.0, 21.0, 50.0]
