// gripper_pid.h - the board's PID: Simulink's parallel form with Forward Euler, exactly the
// equations of gripper_env.pid.pid_update (the parity tests compare them to 1e-9).

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

template <typename Real>
struct PidGains {
    Real p, i, d, n;     // deg/deg, 1/s, s, 1/s
    Real u_min, u_max;   // output limits (deg)
    uint8_t anti_windup; // AntiWindup
    Real kb;             // back-calculation gain (1/s)
    Real sign;           // +1 or -1
    bool d_on_meas;
    // Derived by pid_prepare: the products the equations form first, d * n and dt * n, and
    // whether sign is -1. Computed once per configuration, they give the same numbers as forming
    // them at every sample (the same roundings, in the same order), and save two soft-float
    // multiplications and two by +-1 per tick on the AVR (~500 cycles).
    Real dn, dt_n;
    bool negate;
};

// Fill the derived coefficients of g for the sample time dt (s).
template <typename Real>
inline void pid_prepare(PidGains<Real>& g, Real dt) {
    g.dn = g.d * g.n;
    g.dt_n = dt * g.n;
    g.negate = g.sign < Real(0);
}

// One PID sample. state[0] = xi (integral term), state[1] = xf (filtered derivative input),
// updated in place; g is prepared (pid_prepare) for this dt. Returns u (saturated); *v_out
// receives v (unsaturated) when not null.
template <typename Real>
inline Real pid_update(Real r, Real y, const PidGains<Real>& g, Real dt, Real* state,
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

// Start at rest like gripper_env.pid.PID.reset: output u0 from the integrator and, with the
// derivative on the measurement, no derivative kick at y0.
template <typename Real>
inline void pid_reset(const PidGains<Real>& g, Real u0, Real y0, Real* state) {
    state[0] = u0;
    state[1] = g.d_on_meas ? -g.sign * y0 : Real(0);
}

} // namespace gripper

#endif // GRIPPER_PID_H
