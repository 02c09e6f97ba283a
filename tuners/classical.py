"""Textbook PI tuning from the plant's model: Skogestad's SIMC rule (or IMC/lambda tuning).

Usage::

    python -m tuners.classical --plant test2
    python -m tuners.classical --plant test2 --rule lambda

The baseline a control engineer tries first. The plant's step response over the experiment window
(``window_s`` in ``configs/tuners/classical.yaml``) gives a first-order-plus-dead-time model:

* gain ``k`` = response at the end of the window (the paper's plants behave like gain ~1 over
  seconds: their slow pole/zero pairs must not count, so never the infinite-time DC gain);
* time constant ``tau`` = time to 63.2 % of ``k``;
* dead time ``theta`` = half the servo refresh period (zero-order hold of the 20 ms servo frame)
  + the sensor delay + one sample + ``extra_dead_time_s``.

With the desired closed-loop time constant ``tau_c = max(tau_c_min_s, tau_c_factor * theta)``:

* SIMC (Skogestad 2003): ``Kc = tau / (k (tau_c + theta))``,
  ``tau_I = min(tau, 4 (tau_c + theta))``;
* lambda (IMC-PI): ``Kc = tau / (k (tau_c + theta))``, ``tau_I = tau``;

and the parallel-form gains are ``P = Kc``, ``I = Kc / tau_I``, ``D = 0``.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import control
import numpy as np

from gripper_env.disturbances import Disturbance
from gripper_env.pid import PIDGains
from gripper_env.plants import Plant
from tuners import cli
from tuners.settings import ClassicalSettings, load_settings

__all__ = ["FOPDT", "fit_fopdt", "main", "tune"]


@dataclass(frozen=True)
class FOPDT:
    """First-order-plus-dead-time model ``k exp(-theta s) / (tau s + 1)``.

    Attributes
    ----------
    k : float
        Gain over the window (deg/deg).
    tau_s : float
        Time constant (s).
    theta_s : float
        Dead time (s).
    """

    k: float
    tau_s: float
    theta_s: float


def fit_fopdt(plant: Plant, disturbance: Disturbance, settings: ClassicalSettings) -> FOPDT:
    """Read a FOPDT model off the plant's unit step response over ``settings.window_s``."""
    dt = plant.dt_s
    t = np.arange(0.0, settings.window_s, dt)
    response = control.step_response(control.ss(plant.tf), T=t)
    y = np.ravel(response.outputs)
    k = float(y[-1])
    if not (math.isfinite(k) and abs(k) > 1e-9):
        raise ValueError(f"plant {plant.name}: no usable step response over {settings.window_s} s")
    reached = np.flatnonzero(y / k >= 1.0 - math.exp(-1.0))
    if len(reached) == 0:
        raise ValueError(f"plant {plant.name}: the step response does not reach 63 % in the window")
    tau = max(float(t[reached[0]]), dt)
    theta = (
        disturbance.command.refresh_period_s / 2
        + disturbance.sensor.delay_s
        + dt
        + settings.extra_dead_time_s
    )
    return FOPDT(k=k, tau_s=tau, theta_s=theta)


def tune(model: FOPDT, settings: ClassicalSettings, n: float = 100.0) -> tuple[PIDGains, float]:
    """PI gains by the configured rule; returns the gains and ``tau_c`` (s)."""
    tau_c = max(settings.tau_c_min_s, settings.tau_c_factor * model.theta_s)
    kc = model.tau_s / (model.k * (tau_c + model.theta_s))
    if settings.rule == "simc":
        tau_i = min(model.tau_s, 4.0 * (tau_c + model.theta_s))
    else:
        tau_i = model.tau_s
    return PIDGains(kc, kc / tau_i, 0.0, n), tau_c


def build_parser():
    parser = cli.base_parser(
        "python -m tuners.classical",
        "PI gains from the plant's model by a textbook rule (SIMC or IMC/lambda).",
    )
    parser.add_argument(
        "--rule",
        choices=("simc", "lambda"),
        default=None,
        help="tuning rule (default: the config's 'rule')",
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="rule settings; default configs/tuners/classical.yaml",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(build_parser(), argv)
    start = time.perf_counter()
    inputs = cli.resolve(args)
    settings = load_settings(ClassicalSettings, args.config)
    if args.rule is not None:
        settings = settings.model_copy(update={"rule": args.rule})
    model = fit_fopdt(inputs.plant, inputs.disturbance, settings)
    gains, tau_c = tune(model, settings, inputs.settings.pid.N)
    tuner = "classical" if settings.rule == "simc" else f"classical-{settings.rule}"
    cli.publish(
        args,
        inputs,
        tuner=tuner,
        gains=gains,
        sign=1,
        label=settings.rule,
        tuning={"rule": settings.rule, "fopdt": asdict(model), "tau_c_s": tau_c},
        config={"classical": settings.model_dump()},
        wall_time_s=time.perf_counter() - start,
        notes=[
            f"{settings.rule}: FOPDT k={model.k:.4g} tau={model.tau_s:.4g} s "
            f"theta={model.theta_s:.4g} s, tau_c={tau_c:.4g} s"
        ],
    )
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
