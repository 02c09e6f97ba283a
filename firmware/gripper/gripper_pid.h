// gripper_pid.h - the board's PID: Simulink's parallel form with Forward Euler and the grasp mode,
// exactly the equations of gripper_env.model.pid.pid_grasp_step (the parity tests compare them
// to 1e-9). The grasp mode (gripper_env.model.pid's docstring): once the jaw is blocked short of
// the reference - the command at least grasp_push deg past the filtered measurement, the jaw at
// least grasp_short deg short of the reference and still within grasp_still deg, for
// grasp_dwell ticks - the integrator freezes and the command is held grasp_squeeze deg past the
// contact (the servo's push, so its force and current, bounded); it lets go when the reference
// comes back to or over the contact, or the jaw moves on past it.

#ifndef GRIPPER_PID_H
#define GRIPPER_PID_H

#include <stdint.h>

#include "gripper_messages.h"

// The controller's arithmetic type: float on the board (avr-gcc's double is 32-bit anyway),
// double on the host so the parity tests can compare with the Python PID to 1e-9.
#ifndef GRIPPER_REAL
#if defined(__AVR__)
#define GRIPPER_REAL float
#else
#define GRIPPER_REAL double
#endif
#endif

namespace gripper {

typedef GRIPPER_REAL real_t;

// |x| without the C library (no <math.h> in the shared core): exact, NaN stays NaN.
template <typename Real>
inline Real fabs_real(Real x) { return x < Real(0) ? -x : x; }

template <typename Real>
struct PidGains {
    Real p, i, d, n;     // deg/deg, 1/s, s, 1/s
    Real u_min, u_max;   // output limits (deg)
    uint8_t anti_windup; // AntiWindup
    Real kb;             // back-calculation gain (1/s)
    Real sign;           // +1 or -1
    bool d_on_meas;
    bool grasp;                        // the grasp mode on
    Real squeeze, push, shortfall, still; // its distances (deg)
    uint16_t dwell;                    // its dwell (ticks)
    // Derived by pid_prepare: the products the equations form first, d * n and dt * n, and
    // whether sign is -1. Computed once per configuration, they give the same numbers as forming
    // them at every sample (the same roundings, in the same order), and save two soft-float
    // multiplications and two by +-1 per tick on the AVR (~500 cycles).
    Real dn, dt_n;
    bool negate;
    Real dwell_real; // dwell as a Real, for the count's comparison
};

// Fill the derived coefficients of g for the sample time dt (s).
template <typename Real>
inline void pid_prepare(PidGains<Real>& g, Real dt) {
    g.dn = g.d * g.n;
    g.dt_n = dt * g.n;
    g.negate = g.sign < Real(0);
    g.dwell_real = Real(g.dwell);
}

// Index of each value in a PID state vector: the integral term, the filtered derivative input,
// then the grasp mode's held direction (0 none, -1 closing, +1 opening), contact (or where the
// jaw stopped; deg), ticks blocked so far, filtered measurement (deg).
enum PidStateIndex { PID_XI, PID_XF, PID_HELD, PID_AT, PID_COUNT, PID_YF, PID_STATE_SIZE };

// The grasp mode's measurement filter per tick, a power of two (GRASP_FILTER in Python).
const float GRASP_FILTER = 0.125f;

// One plain PID sample. state[0] = xi (integral term), state[1] = xf (filtered derivative
// input), updated in place; g is prepared (pid_prepare) for this dt. Returns u (saturated);
// *v_out receives v (unsaturated) when not null.
template <typename Real>
inline Real pid_step(Real r, Real y, const PidGains<Real>& g, Real dt, Real* state,
                     Real* v_out) {
    Real e = g.negate ? -(r - y) : r - y;   // sign * (r - y), exactly
    Real s = g.d_on_meas ? (g.negate ? y : -y) : e; // -sign * y, exactly
    Real xi = state[0];
    Real xf = state[1];
    Real deriv = g.dn * (s - xf);
    Real v = g.p * e + xi + deriv;
    Real u = v;
    if (u > g.u_max) {
        u = g.u_max;
    } else if (u < g.u_min) {
        u = g.u_min;
    }
    Real ui = g.i * e;
    if (g.anti_windup == AW_CLAMPING) {
        if (u != v && ui * (v - u) > Real(0)) ui = Real(0);
    } else if (g.anti_windup == AW_BACK_CALCULATION) {
        ui += g.kb * (u - v);
    }
    state[0] = xi + dt * ui;
    state[1] = xf + g.dt_n * (s - xf);
    if (v_out) *v_out = v;
    return u;
}

// The grasp mode's command: squeeze past the contact `at` in the direction `held` (+-1), never
// past the reference r, inside the output limits (gripper_env.model.pid.grasp_hold).
template <typename Real>
inline Real grasp_hold(Real at, Real held, Real r, const PidGains<Real>& g) {
    Real past = held * (r - at);
    if (past > g.squeeze) {
        past = g.squeeze;
    } else if (past < Real(0)) {
        past = Real(0);
    }
    Real u = at + held * past;
    if (u > g.u_max) {
        u = g.u_max;
    } else if (u < g.u_min) {
        u = g.u_min;
    }
    return u;
}

// One PID sample with the grasp mode (gripper_env.model.pid.pid_grasp_step): state has
// PID_STATE_SIZE values, updated in place. Without the mode, pid_step and state[0..1] only.
template <typename Real>
inline Real pid_update(Real r, Real y, const PidGains<Real>& g, Real dt, Real* state,
                       Real* v_out) {
    if (!g.grasp) return pid_step<Real>(r, y, g, dt, state, v_out);
    Real yf = state[PID_YF] + Real(GRASP_FILTER) * (y - state[PID_YF]);
    state[PID_YF] = yf;
    Real held = state[PID_HELD];
    if (held != Real(0) &&
        (held * (r - state[PID_AT]) <= Real(0) || held * (yf - state[PID_AT]) > g.still)) {
        // let go: opening, or the object gave way; the integrator resumes from the command
        state[PID_XI] = grasp_hold<Real>(state[PID_AT], held, r, g);
        held = Real(0);
        state[PID_HELD] = held;
        state[PID_COUNT] = Real(0);
        state[PID_AT] = yf;
    }
    Real xi_frozen = state[PID_XI];
    Real u = pid_step<Real>(r, y, g, dt, state, v_out);
    if (held == Real(0)) {
        // Python's direction * (u - yf) and direction * (r - yf), as branches (a product by +-1
        // is exact, and a soft-float multiplication on the AVR costs more than a sign flip).
        // While the jaw moves freely the first test fails and the rest is skipped.
        Real d = u - yf;
        bool up = d > Real(0);
        if ((up ? d : -d) >= g.push && (up ? r - yf : yf - r) >= g.shortfall &&
            fabs_real(yf - state[PID_AT]) <= g.still) {
            state[PID_COUNT] += Real(1);
            if (state[PID_COUNT] < g.dwell_real) return u;
        } else {
            state[PID_COUNT] = Real(0);
            state[PID_AT] = yf;
            return u;
        }
        held = up ? Real(1) : Real(-1); // blocked for the dwell: hold from this tick
        state[PID_HELD] = held;
        state[PID_AT] = yf;
        state[PID_COUNT] = Real(0);
    }
    // holding: the integrator frozen, the derivative filter running on
    state[PID_XI] = xi_frozen;
    u = grasp_hold<Real>(state[PID_AT], held, r, g);
    if (v_out) *v_out = u;
    return u;
}

// Start at rest like gripper_env.model.pid.PID.reset: output u0 from the integrator, with the
// derivative on the measurement no derivative kick at y0, no grasp (the jaw standing at y0).
template <typename Real>
inline void pid_reset(const PidGains<Real>& g, Real u0, Real y0, Real* state) {
    state[PID_XI] = u0;
    state[PID_XF] = g.d_on_meas ? -g.sign * y0 : Real(0);
    state[PID_HELD] = Real(0);
    state[PID_AT] = y0;
    state[PID_COUNT] = Real(0);
    state[PID_YF] = y0;
}

} // namespace gripper

#endif // GRIPPER_PID_H
