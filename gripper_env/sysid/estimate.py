"""An identified continuous-time transfer function with input delay, and how well it fits.

:class:`TFEstimate` is what :func:`gripper_env.sysid.tfest` returns: the model, its fits (on the
estimation data; on validation data, :class:`FitOnData`, when there are some), its parameters
with standard errors, the delay, the operating point and the diagnostics; it simulates itself
(:meth:`TFEstimate.simulate`) and prints like the paper (:meth:`TFEstimate.paper_form`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import control
import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import norm

from gripper_env.model.state_space import observer_form
from gripper_env.sysid.zoh import zoh_response

__all__ = ["FitOnData", "TFEstimate", "format_polynomial", "param_names", "rest_state"]


def format_polynomial(coeffs: ArrayLike, var: str = "s", precision: int = 4) -> str:
    """Polynomial as text, highest power first: ``[1, 22, 200] -> "s^2 + 22 s + 200"``.

    Zero coefficients are left out, a unit coefficient in front of a power of ``var`` is not
    written, and numbers use ``precision`` significant digits.
    """
    c = np.asarray(coeffs, dtype=float)
    deg = c.size - 1
    terms: list[str] = []
    for i, value in enumerate(c):
        if value == 0:
            continue
        power = deg - i
        mag = abs(value)
        num = f"{mag:.{precision}g}"
        if power == 0:
            body = num
        else:
            v = var if power == 1 else f"{var}^{power}"
            body = v if num == "1" else f"{num} {v}"
        if not terms:
            terms.append(f"-{body}" if value < 0 else body)
        else:
            terms.append(f"- {body}" if value < 0 else f"+ {body}")
    return " ".join(terms) if terms else "0"


def rest_state(
    num: ArrayLike, den: ArrayLike, y0: float, u0: float
) -> np.ndarray:  # observer-form state
    """Observer-form state at which the model rests with output ``y0`` under the input ``u0``.

    The output and its first ``n - 1`` derivatives are ``y0, 0, ..., 0``: at rest where it is,
    whatever the model's gain (a model with an integrator, or with a slow pole, starts still
    rather than drifting toward an equilibrium that does not exist or lies far away).
    """
    a_mat, b, _, d = observer_form(num, den)
    n = a_mat.shape[0]
    x0 = np.zeros(n)
    x0[0] = y0 - d * u0
    for i in range(n - 1):
        # derivative of state i: a[i, 0] x0 + x[i + 1] + b[i] u0 = 0
        x0[i + 1] = -(a_mat[i, 0] * x0[0] + b[i] * u0)
    return x0


@dataclass(frozen=True)
class FitOnData:
    """How well a model reproduces one record (MATLAB ``compare``).

    Attributes
    ----------
    fit_pct : float
        Fit (%) with the initial state estimated on this record.
    fit_pct_rest : float
        Fit (%) simulated from rest at the record's first (rest) output: nothing fitted.
    n_samples : int
        Samples compared.
    source : str
        Which data: ``"estimation"``, ``"split"`` (the held-out end of the record) or a file.
    """

    fit_pct: float
    fit_pct_rest: float
    n_samples: int
    source: str

    def to_dict(self) -> dict[str, Any]:
        return {
            "fit_pct": json_float(self.fit_pct),
            "fit_pct_rest": json_float(self.fit_pct_rest),
            "n_samples": int(self.n_samples),
            "source": self.source,
        }


@dataclass(frozen=True)
class TFEstimate:
    """An identified continuous-time transfer function with input delay, and how well it fits.

    Attributes
    ----------
    model : control.TransferFunction
        ``G(s)`` from input deviation to output deviation (deg/deg, time in s), monic
        denominator; the input delay is :attr:`input_delay_s`.
    fit_pct : float
        MATLAB ``compare`` fit (%) on the *estimation* data with the estimated initial state:
        ``100 * (1 - ||y - yhat|| / ||y - mean(y)||)``. The figure to trust is
        :attr:`validation`'s.
    fit_pct_rest : float
        Fit (%) on the estimation data simulated from rest at the first output
        (:func:`rest_state`), nothing fitted to the record.
    residuals : ndarray
        ``y - yhat`` with the estimated initial state (deg), one per (gridded) sample.
    params : ndarray
        ``[a_{n-1}, ..., a_0, b_m, ..., b_0]`` of ``(b_m s^m + ... + b_0) / (s^n + ... + a_0)``.
    params_std : ndarray
        Standard errors of ``params`` from the output-error Jacobian under the error model of
        :mod:`gripper_env.sysid.error_model`: white noise plus the time stamps' jitter (and the
        robust loss's sandwich); ``inf`` where not identifiable. They are optimistic when the
        residuals are coloured (a model that misses part of the dynamics).
    param_names : tuple of str
        ``("a1", "a0", "b1", "b0")`` style names of ``params``.
    initial_state : ndarray
        Estimated state at the first sample, observer canonical form
        (:func:`gripper_env.model.state_space.observer_form`), deviation units.
    initial_state_std : ndarray
        Standard errors of ``initial_state``.
    stable : bool
        All poles strictly in the left half plane.
    dt_s : float
        Sample interval of the data (s).
    u_op, y_op : float
        Operating point (deg); ``y_op`` refined jointly with the model by default.
    y_op_std : float
        Standard error of ``y_op`` (deg; 0 when it was not estimated).
    offset : str
        How the operating point was chosen (``"initial"``, ``"mean"`` or ``"none"``).
    input_delay_s : float
        Input delay ``tau`` of ``G(s) e^{-s tau}`` (s).
    input_delay_std_s : float
        Its standard error (s; 0 when it was fixed).
    delay_estimated : bool
        Whether the delay was estimated (else fixed by the caller).
    n_iter_srivc, n_iter_oe : int
        SRIVC and output-error (trust-region) iterations.
    converged : bool
        Whether the output-error search met its tolerance.
    svf_lambda_rad_s : float
        Pole of the state-variable filter of the winning start (rad/s; NaN for a start from
        another estimate).
    time_base : str
        How the time stamps were handled (:class:`gripper_env.sysid.data.IOData`).
    jitter : float
        Largest time-stamp deviation from the uniform grid (fraction of an interval).
    jitter_std : float
        Standard deviation of the snapped time stamps about the grid (fraction of an
        interval), which the standard errors include.
    closed_loop : dict or None
        With a reference (the closed-loop estimator): the fitted controller
        (``controller_num``, ``controller_den``), how well the input follows it
        (``controller_fit_pct``) and how well the simulated loop reproduces the output from the
        reference (``loop_fit_pct``). None for open-loop data.
    warnings : tuple of str
        Diagnostics (also issued as :class:`IdentificationWarning`).
    validation : FitOnData or None
        Fit on validation data, when some was given (:func:`gripper_env.sysid.orders.validate`).
    message : str
        The optimiser's stopping message.
    loss : str
        Loss of the output-error search (``"linear"``: least squares).
    delay_candidates_s : tuple of float
        Delays the global delay search refitted, best first (s; empty with the delay fixed).
    """

    model: control.TransferFunction
    fit_pct: float
    fit_pct_rest: float
    residuals: np.ndarray = field(repr=False)
    params: np.ndarray
    params_std: np.ndarray
    param_names: tuple[str, ...]
    initial_state: np.ndarray
    initial_state_std: np.ndarray
    stable: bool
    dt_s: float
    u_op: float
    y_op: float
    y_op_std: float
    offset: str
    input_delay_s: float = 0.0
    input_delay_std_s: float = 0.0
    delay_estimated: bool = False
    n_iter_srivc: int = 0
    n_iter_oe: int = 0
    converged: bool = True
    svf_lambda_rad_s: float = math.nan
    time_base: str = "interval"
    jitter: float = 0.0
    closed_loop: dict[str, Any] | None = None
    warnings: tuple[str, ...] = ()
    validation: FitOnData | None = None
    message: str = ""
    jitter_std: float = 0.0
    loss: str = "linear"
    delay_candidates_s: tuple[float, ...] = ()

    @property
    def num(self) -> np.ndarray:
        """Numerator coefficients, highest power of ``s`` first."""
        return np.asarray(self.model.num[0][0], dtype=float)

    @property
    def den(self) -> np.ndarray:
        """Monic denominator coefficients, highest power of ``s`` first."""
        return np.asarray(self.model.den[0][0], dtype=float)

    @property
    def n_poles(self) -> int:
        return self.den.size - 1

    @property
    def n_zeros(self) -> int:
        return self.params.size - self.n_poles - 1

    @property
    def poles(self) -> np.ndarray:
        """Poles (rad/s)."""
        return np.roots(self.den)

    @property
    def zeros(self) -> np.ndarray:
        """Zeros (rad/s)."""
        return np.roots(self.num) if self.num.size > 1 else np.array([], dtype=complex)

    @property
    def resampled(self) -> bool:
        """Whether irregular time stamps were resampled."""
        return self.time_base == "resampled"

    @property
    def n_model_params(self) -> int:
        """Parameters of the model proper: coefficients, plus the delay when estimated."""
        return self.params.size + int(self.delay_estimated)

    @property
    def aic(self) -> float:
        """Akaike's information criterion on the estimation data, ``N log(V) + 2 k`` with the
        mean squared residual ``V`` and ``k`` :attr:`n_model_params` (as MATLAB's ``aic``,
        which does not count the initial state)."""
        n = self.residuals.size
        v = float(np.mean(self.residuals**2))
        return n * math.log(max(v, 1e-300)) + 2 * self.n_model_params

    def intervals(self, level: float = 0.95) -> dict[str, tuple[float, float]]:
        """Confidence intervals of the coefficients (by :attr:`param_names`) and, when it was
        estimated, of the input delay (``"input_delay_s"``, s; not below 0): estimate +/- the
        normal quantile times the standard error."""
        z = float(norm.ppf(0.5 + 0.5 * level))
        out = {
            k: (float(v - z * sd), float(v + z * sd))
            for k, v, sd in zip(self.param_names, self.params, self.params_std, strict=True)
        }
        if self.delay_estimated:
            tau, sd = self.input_delay_s, self.input_delay_std_s
            out["input_delay_s"] = (max(0.0, tau - z * sd), tau + z * sd)
        return out

    @property
    def headline_fit_pct(self) -> float:
        """The fit to quote: on validation data when there are some, else on estimation data."""
        return self.validation.fit_pct if self.validation is not None else self.fit_pct

    def paper_form(self, precision: int = 4) -> str:
        """The transfer function as the paper prints it, e.g.
        ``"(20 s + 200) / (s^2 + 22 s + 200)"``, with ``exp(-0.015 s)`` when delayed."""
        num = format_polynomial(self.num, precision=precision)
        den = format_polynomial(self.den, precision=precision)
        if np.count_nonzero(self.num) > 1:
            num = f"({num})"
        text = f"{num} / ({den})"
        if self.input_delay_s > 0:
            text += f" exp(-{self.input_delay_s:.{precision}g} s)"
        return text

    def rest_state(self, y0: float, u0: float) -> np.ndarray:
        """Observer-form state (deviations) at rest with output ``y0`` under input ``u0``, both
        absolute (deg); see :func:`rest_state`."""
        return rest_state(self.num, self.den, y0 - self.y_op, u0 - self.u_op)

    def simulate(self, u: ArrayLike, initial_state: ArrayLike | None = None) -> np.ndarray:
        """Simulate the model on an absolute input, with the operating point restored.

        Parameters
        ----------
        u : array_like
            Input (deg), sampled every ``dt_s`` and held between samples; before the first
            sample it is taken to have been ``u[0]`` (the delay reads back into that).
        initial_state : array_like, optional
            State at the first sample (observer form, deviation units). Default: the estimated
            :attr:`initial_state`, which belongs to the identification record; pass zeros for a
            start at rest at the operating point, or :meth:`rest_state`.

        Returns
        -------
        ndarray
            Output (deg): ``y_op + G e^{-s tau} (u - u_op)`` plus the free response of the
            initial state.
        """
        u_arr = np.asarray(u, dtype=float)
        x0 = self.initial_state if initial_state is None else np.asarray(initial_state, float)
        return self.y_op + zoh_response(
            self.num, self.den, u_arr - self.u_op, self.dt_s, x0, self.input_delay_s
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly summary (plain floats and lists)."""
        out: dict[str, Any] = {
            "num": [float(c) for c in self.num],
            "den": [float(c) for c in self.den],
            "input_delay_s": float(self.input_delay_s),
            "input_delay_std_s": json_float(self.input_delay_std_s),
            "delay_estimated": bool(self.delay_estimated),
            "paper_form": self.paper_form(),
            "validation": None if self.validation is None else self.validation.to_dict(),
            "fit_pct": json_float(self.fit_pct),
            "fit_pct_rest": json_float(self.fit_pct_rest),
            "aic": json_float(self.aic),
            "params": {k: float(v) for k, v in zip(self.param_names, self.params, strict=True)},
            "params_std": {
                k: json_float(v) for k, v in zip(self.param_names, self.params_std, strict=True)
            },
            "poles": [[float(p.real), float(p.imag)] for p in self.poles],
            "zeros": [[float(z.real), float(z.imag)] for z in self.zeros],
            "stable": bool(self.stable),
            "initial_state": [float(x) for x in self.initial_state],
            "dt_s": float(self.dt_s),
            "n_samples": int(self.residuals.size),
            "time_base": self.time_base,
            "jitter": float(self.jitter),
            "u_op": float(self.u_op),
            "y_op": float(self.y_op),
            "y_op_std": float(self.y_op_std),
            "offset": self.offset,
            "closed_loop": self.closed_loop,
            "residual_rms": float(np.sqrt(np.mean(self.residuals**2))),
            "n_iter_srivc": int(self.n_iter_srivc),
            "n_iter_oe": int(self.n_iter_oe),
            "converged": bool(self.converged),
            "svf_lambda_rad_s": json_float(self.svf_lambda_rad_s),
            "loss": self.loss,
            "jitter_std": float(self.jitter_std),
            "delay_candidates_s": [float(d) for d in self.delay_candidates_s],
            "intervals_95": {
                k: [json_float(lo), json_float(hi)] for k, (lo, hi) in self.intervals().items()
            },
            "warnings": list(self.warnings),
        }
        return out


def json_float(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def param_names(n: int, m: int) -> tuple[str, ...]:
    return tuple(f"a{j}" for j in range(n - 1, -1, -1)) + tuple(f"b{k}" for k in range(m, -1, -1))
