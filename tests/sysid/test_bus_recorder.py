"""The bus recorder's time stamps: each reading at the middle of its round trip, each goal when
sent (its latency counts as delay: the safe side), every round trip kept with its reading; a
slow one (a loaded host, a USB latency timer) counted and kept in the record, and left out of
the fit rather than fitted with a stamp several ms off."""

from __future__ import annotations

import numpy as np

from gripper_env.model.bus_servo import load_bus_servo
from gripper_env.sysid.bus_experiments import BusRecorder, GoalPlan


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        self.t += 1e-6  # reading the clock takes time too (the recorder's short waits spin)
        return self.t


class _ScriptedServo:
    """A servo whose replies take 0.4 ms, every 25th reading 9 ms; it reports the time at which
    it answered (the middle of the round trip) as its position, so stamps can be checked."""

    def __init__(self, clock: _Clock) -> None:
        self.model = load_bus_servo("sts3215")
        self.calibration = None  # what the record carries: a real servo's jaw calibration
        self.clock = clock
        self.reads = 0
        self.goal_times: list[float] = []
        self.log: list[tuple[int, bool]] = []

    def _trip(self, seconds: float) -> float:
        self.clock.t += seconds / 2
        answered = self.clock.t
        self.clock.t += seconds / 2
        return answered

    def write_registers(self, regs):
        return regs

    def torque(self, on: bool) -> None:
        pass

    def goal_deg(self, angle: float) -> float:
        self.goal_times.append(self._trip(0.0006))
        return angle

    def position_deg(self, retries: int | None = None) -> float:
        self.reads += 1
        slow = self.reads % 25 == 0
        self.log.append((len(self.goal_times), slow))  # goals sent so far, and how it went
        return self._trip(0.009 if slow else 0.0004)


def test_readings_are_stamped_at_the_middle_and_slow_ones_kept_with_their_round_trips(
    monkeypatch,
):
    clock = _Clock()
    monkeypatch.setattr("time.sleep", lambda s: setattr(clock, "t", clock.t + s))
    servo = _ScriptedServo(clock)
    recorder = BusRecorder(servo, sample_s=0.002, clock=clock)  # type: ignore[arg-type]
    plan = GoalPlan(times_s=np.array([0.0, 0.1, 0.2]), goals_deg=np.array([240.0, 230.0, 240.0]),
                    duration_s=0.4)  # fmt: skip
    rec = recorder.record(servo.model.factory, plan)
    # the record's readings: after its first goal (the settle before it sent one already)
    during = [was_slow for goals, was_slow in servo.log if goals >= 2]
    reads, slow = len(during), sum(during)
    assert slow >= 3 and recorder.slow == slow
    assert rec.t_s.size == reads and rec.stats == {
        "readings": reads,
        "lost": 0,
        "slow": slow,
        "sample_us": 2000,
    }
    # every reading keeps its round trip: the slow ones 9 ms, the others 0.4 ms
    assert np.sum(rec.rtt_s > 0.005) == slow
    assert np.allclose(rec.rtt_s[rec.rtt_s < 0.005], 0.0004, atol=1e-5)
    assert np.allclose(rec.goal_rtt_s, 0.0006, atol=1e-5)
    # each kept reading's stamp is when the servo answered (its "position" here), from the
    # record's start: the same offset for every reading
    offset = rec.position_deg - rec.t_s
    assert np.ptp(offset) < 5e-6
    # and each goal's stamp is when it was sent: half its round trip before the servo took it
    took = np.array(servo.goal_times[-3:]) - offset[0]
    assert np.allclose(took - 0.0003, rec.goal_times_s, atol=5e-6)


def test_the_fit_leaves_out_the_slow_readings_the_record_keeps():
    """``reading_weights``: round trips of 1 ms but two of 11 ms (over 3x the median): those two
    weigh 0, the rest 1; a record without round trips (simulated, or an older file) uses all."""
    from gripper_env.sysid.bus_servo import BusRecord, reading_weights

    model = load_bus_servo("sts3215")
    t = np.arange(20) * 0.002
    y = np.full(t.size, 240.0)
    rtt = np.full(t.size, 0.001)
    rtt[[3, 15]] = 0.011
    rtt[7] = 0.0019  # slower than 3x the median but within the 2 ms floor: kept
    rec = BusRecord("sts3215", model.factory, t, y, y, np.array([0.0]), np.array([240.0]),
                    rtt_s=rtt)  # fmt: skip
    w = reading_weights(rec)
    assert w[[3, 15]].tolist() == [0.0, 0.0] and np.all(np.delete(w, [3, 15]) == 1.0)
    plain = BusRecord("sts3215", model.factory, t, y, y, np.array([0.0]), np.array([240.0]))
    assert np.all(reading_weights(plain) == 1.0)
