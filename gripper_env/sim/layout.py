"""Column layout of the core's arrays: one row per run, a column per parameter or state value.

The compiled kernel (:mod:`gripper_env.sim.kernel`) reads a run's parameters from a row of the
``params`` matrix (``P_*`` columns, built by :func:`gripper_env.sim.params.build_params`) and
its state from a row of the ``state`` matrix (``S_*`` columns); the environments' kernels read
and write some of these columns too. Angles are in deg, times in physics steps unless named.
"""

from __future__ import annotations

__all__ = ["DIVERGENCE_BOUND", "N_PARAMS", "state_width"]

# ----------------------------------------------------------------------------------------------
# Parameter row: the controller, then the actual-gripper blocks in signal order.
# PID (gripper_env.model.pid): gains, output limits (deg), back-calculation gain (1/s), error sign,
# anti-windup mode, derivative on measurement (0/1).
P_P, P_I, P_D, P_N, P_ULO, P_UHI, P_KB, P_SIGN, P_AW, P_DMEAS = range(10)
# the PID's grasp mode (gripper_env.model.pid.GraspOptions): on (0/1), squeeze, push, short and
# still (deg), dwell (steps)
P_GRASP, P_SQUEEZE, P_PUSH, P_SHORT, P_STILL, P_DWELL = range(10, 16)
# servo command path (sim.servo): range (deg), quantum (deg), refresh period (steps), rate (deg/s)
P_CMD_LO, P_CMD_HI, P_QUANTUM, P_REFRESH, P_RATE = range(16, 21)
# friction (sim.friction): model code, S and J (deg), backlash width (deg)
P_FRIC, P_S, P_J, P_BACKLASH = range(21, 25)
# mechanics (sim.mechanics): stops (deg; an object in the jaws raises the lower one)
P_MECH_LO, P_MECH_HI = range(25, 27)
# sensor (sim.sensor): ADC step (deg), ADC range start (deg), largest code, noise (deg), delay
P_ADC_LSB, P_ADC_LO, P_ADC_MAX, P_NOISE, P_DELAY = range(27, 32)
# mechanics: command beyond a stop (deg) that stalls the servo
P_STALL_BAND = 32
N_PARAMS = 33

# ----------------------------------------------------------------------------------------------
# Friction state (sim.friction): a vector of F_SIZE values, at S_FRIC in a state row.
F_OUT = 0  # output position (deg)
F_XPREV = 1  # previous input (deg)
F_XSS = 2  # input where the jaw stuck (deg)
F_DIR = 3  # direction of the last motion: -1, 0 (none yet), +1
F_STUCK = 4  # 1 while stuck
F_SIZE = 5

# ----------------------------------------------------------------------------------------------
# State row: controller, command path, friction, sensor, counters, then the plant.
S_XI, S_XF = 0, 1  # PID integrator term and derivative filter state
# the PID's grasp mode: held direction (0 none, -1 closing, +1 opening), contact or where the jaw
# stopped (deg), steps blocked so far, filtered measurement (deg)
S_GRASP, S_GRASP_AT, S_GRASP_COUNT, S_GRASP_YF = 2, 3, 4, 5
S_CMD, S_COUNTDOWN = 6, 7  # held servo command (deg), physics steps to the next refresh tick
S_FRIC = 8  # F_SIZE entries
S_BACKLASH = S_FRIC + F_SIZE  # backlash output (deg)
S_DIDX = S_BACKLASH + 1  # write position in the sensor's delay line
S_VPREV = S_DIDX + 1  # plant input of the previous step (deg)
S_YMEAS = S_VPREV + 1  # last measured angle (deg)
S_U = S_YMEAS + 1  # last controller output (deg)
S_DIVERGED = S_U + 1  # 1 once the run left the divergence bound
S_SATURATED = S_DIVERGED + 1  # count of steps with the command clipped
S_CMDCLIP = S_SATURATED + 1  # 1 while the held servo command is clipped to its range
S_STEPS = S_CMDCLIP + 1  # physics steps advanced so far
S_CONTACT = S_STEPS + 1  # steps with the jaw held by a stop or an object
S_STALL = S_CONTACT + 1  # steps held there with the command a whole stall band beyond it
S_FORCE = S_STALL + 1  # sum over steps of the push as a fraction of stall torque
S_SERVO_TV = S_FORCE + 1  # total variation of the servo command (deg)
S_X = S_SERVO_TV + 1  # plant state, then as many entries of scratch space

#: A run whose plant state or controller output leaves +/- this bound is diverged.
DIVERGENCE_BOUND = 1e9


def state_width(n_x: int) -> int:
    """Columns of a state row for plants of order up to ``n_x`` (state plus scratch space)."""
    return S_X + 2 * n_x
