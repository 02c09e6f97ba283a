"""Identify a transfer function from an open-loop record of the simulated actual gripper.

The paper identified its four transfer functions with MATLAB's ``tfest`` from open-loop records
of the real gripper. Here the gripper is the simulation core (:func:`gripper_env.sim.simulate`:
a known plant behind the ``actual`` preset's servo, friction, stops, noise and 10-bit ADC), so
the identified model can be compared with the truth:

1. record the profile open loop (the desired angle is the servo command), as
   ``python -m tuners.rig.record`` does on a board;
2. fit 2 poles and 1 zero, the paper's structure, with :func:`gripper_env.sysid.tfest`
   (SRIVC start, output-error refinement; several starts, like ``InitializeMethod = 'all'``);
3. compare with the true plant: the fast pole, the step response's 63 % time, and the fit % of
   both models on a validation record they were not estimated from.

Run::

    python examples/identify.py                       # step record of test2, a few seconds
    python examples/identify.py --profile slope20     # the paper's test-4 slope (slower)
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from gripper_env.evaluation.metrics import fit_percent
from gripper_env.model.plants import load_plant
from gripper_env.model.references import PROFILES
from gripper_env.sim import simulate
from gripper_env.sysid import tfest
from gripper_env.sysid.estimate import format_polynomial
from gripper_env.sysid.experiments import SVF_LAMBDAS, step_t63, validation_reference


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plant", default="test2", help="the true plant (default: test2)")
    parser.add_argument(
        "--profile", default="step", choices=sorted(PROFILES), help="record (default: step)"
    )
    parser.add_argument("--disturbance", default="actual", help="preset (default: actual)")
    parser.add_argument("--seed", type=int, default=1, help="noise seed of the record")
    args = parser.parse_args(argv)

    truth = load_plant(args.plant)
    # 1. an open-loop record: gains=None sends the reference straight to the servo
    record = simulate(
        truth, args.profile, gains=None, disturbance=args.disturbance, seeds=args.seed
    )
    u, y = record.r[0], record.y[0]  # desired angle, measured angle (noise and ADC included)
    print(f"record: {args.profile} on {args.plant} behind '{args.disturbance}', {len(u)} samples")

    # 2. the paper's structure: 2 poles, 1 zero, no delay, initial state estimated
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # tfest explains what the data cannot see, as warnings
        est = tfest(record.t, u, y, n_poles=2, n_zeros=1, svf_lambda_rad_s=list(SVF_LAMBDAS))
    print(f"identified: {est.paper_form()}, fit {est.fit_pct:.1f} % on the record")
    for w in caught:
        print(f"  note: {str(w.message).splitlines()[0]}")
    lead = truth.den[0]  # the paper prints a leading 2 in test2's denominator
    print(
        f"true plant: ({format_polynomial(np.divide(truth.num, lead))}) / "
        f"({format_polynomial(np.divide(truth.den, lead))})"
    )

    # 3. against the truth
    fast_est, fast_true = np.min(est.poles.real), np.min(truth.poles.real)
    t63_est = step_t63(est.num, est.den, est.dt_s)
    t63_true = step_t63(truth.num, truth.den, truth.dt_s)
    print(f"fast pole: {fast_est:.2f} rad/s (true {fast_true:.2f}); 63 % of a step in "
          f"{t63_est * 1e3:.0f} ms (true {t63_true * 1e3:.0f} ms)")  # fmt: skip
    # a validation record: the paper's direct-response profile, another noise seed
    val = simulate(
        truth, validation_reference(hold_s=10.0), gains=None, disturbance=args.disturbance,
        seeds=args.seed + 1,
    )  # fmt: skip
    u_val, y_val = val.r[0], val.y[0]
    y0 = float(np.mean(y_val[:500]))  # at rest for the first second
    y_est = est.simulate(u_val, est.rest_state(y0, float(u_val[0])))
    y_true_tf = simulate(truth, u_val, gains=None, disturbance="ideal", y0_deg=y0).y[0]
    print(
        f"fit on a validation record: identified {float(fit_percent(y_val, y_est)):.1f} %, "
        f"true transfer function alone {float(fit_percent(y_val, y_true_tf)):.1f} %"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
