"""Validation data and the choice of model order.

A fit on the data a model was estimated from flatters it: more parameters always fit better
there. The honest figures are on data the estimator did not see:

- :func:`validate` scores an estimate on another record (MATLAB ``compare``: fit % with the
  initial state estimated on that record, and from rest at its first sample);
- :func:`split_record` holds out the end of one record for that;
- :func:`compare_orders` estimates several orders (lower ones first, each higher order also
  started from the best lower order it contains, so it fits the estimation data at least as
  well), scores them on validation data and Akaike's criterion, and picks one.

Order selection rule (:data:`FIT_TOLERANCE_PCT`): with validation data, the highest validation
fit, except that a model with fewer parameters within ``FIT_TOLERANCE_PCT`` points of it wins
(parsimony: such differences are within the noise of the fit); without validation data, the
smallest AIC. An order whose output-error search did not converge is listed but not chosen
while any order converged: its figures are those of wherever the search stopped, and a
record's noise decides whether a high order converges, so choosing it made the outcome of
``--orders`` depend on the noise draw.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from gripper_env.evaluation.metrics import fit_percent
from gripper_env.sysid.data import DEFAULT_MAX_GAP, DEFAULT_MAX_JITTER, IOData, prepare_data
from gripper_env.sysid.output_error import fit_initial_state
from gripper_env.sysid.tfest import FitOnData, TFEstimate, tfest

__all__ = [
    "FIT_TOLERANCE_PCT",
    "OrderRow",
    "OrderSelection",
    "Record",
    "choose_order",
    "compare_orders",
    "parse_orders",
    "split_record",
    "validate",
]

#: Validation-fit points within which the simpler model is preferred.
FIT_TOLERANCE_PCT = 0.5


@dataclass(frozen=True)
class Record:
    """One record: time (``dt_s`` or stamps), input, output, optional reference (deg)."""

    time_s: float | np.ndarray
    u: np.ndarray
    y: np.ndarray
    r: np.ndarray | None = None

    @property
    def n_samples(self) -> int:
        return int(np.asarray(self.u).size)


def parse_orders(text: str) -> list[tuple[int, int]]:
    """``"1/0,2/1,4/2"`` -> ``[(1, 0), (2, 1), (4, 2)]`` (poles/zeros), checked.

    Raises
    ------
    ValueError
        Malformed text or an improper order.
    """
    orders = []
    for part in text.split(","):
        match = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", part)
        if not match:
            raise ValueError(
                f"--orders: {part.strip()!r} is not POLES/ZEROS (e.g. --orders 1/0,2/1,3/1)"
            )
        n, m = int(match[1]), int(match[2])
        if n < 1 or m > n:
            raise ValueError(
                f"--orders: {n}/{m} is not a proper model (need poles >= 1, zeros <= poles)"
            )
        if (n, m) not in orders:
            orders.append((n, m))
    if not orders:
        raise ValueError("--orders needs at least one POLES/ZEROS pair")
    return orders


def split_record(record: Record, fraction: float) -> tuple[Record, Record]:
    """Estimation part (the start) and validation part (the last ``fraction``) of a record.

    Raises
    ------
    ValueError
        ``fraction`` outside ``(0, 1)``.
    """
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"--split must be a fraction between 0 and 1, got {fraction}")
    n = record.n_samples
    k = round(n * (1.0 - fraction))
    k = min(max(k, 2), n - 2)

    def part(sl: slice) -> Record:
        t = record.time_s if np.ndim(record.time_s) == 0 else np.asarray(record.time_s)[sl]
        r = None if record.r is None else np.asarray(record.r)[sl]
        return Record(t, np.asarray(record.u)[sl], np.asarray(record.y)[sl], r)

    return part(slice(0, k)), part(slice(k, n))


def validate(
    est: TFEstimate,
    record: Record,
    source: str,
    *,
    max_jitter: float = DEFAULT_MAX_JITTER,
    max_gap: float = DEFAULT_MAX_GAP,
) -> FitOnData:
    """How well ``est`` reproduces another record (MATLAB ``compare``).

    The model is sampled at the record's own interval. ``fit_pct`` estimates the initial state
    on the record (not the operating point: that belongs to the model); ``fit_pct_rest`` starts
    the model at rest at the record's first output (the mean over the samples before the input
    first moves).
    """
    data = prepare_data(
        record.time_s, record.u, record.y, offset="none", max_jitter=max_jitter, max_gap=max_gap
    )
    if not math.isclose(data.dt_s, est.dt_s, rel_tol=1e-9):
        est = dataclasses.replace(est, dt_s=data.dt_s)
    u_abs, y_abs = data.u, data.y
    dev = IOData(
        dt_s=data.dt_s,
        t0_s=data.t0_s,
        u=u_abs - est.u_op,
        y=y_abs - est.y_op,
        u_op=est.u_op,
        y_op=est.y_op,
        offset=est.offset,
    )
    _, _, y_hat = fit_initial_state(dev, est.num, est.den, delay_s=est.input_delay_s)
    moved = np.flatnonzero(u_abs != u_abs[0])
    k = int(moved[0]) if moved.size else u_abs.size
    x_rest = est.rest_state(float(np.mean(y_abs[: max(k, 1)])), float(u_abs[0]))
    y_rest = est.simulate(u_abs, x_rest)
    return FitOnData(
        fit_pct=float(fit_percent(y_abs, y_hat + est.y_op)),
        fit_pct_rest=float(fit_percent(y_abs, y_rest)),
        n_samples=data.n_samples,
        source=source,
    )


@dataclass(frozen=True)
class OrderRow:
    """One candidate order."""

    n_poles: int
    n_zeros: int
    estimate: TFEstimate

    @property
    def label(self) -> str:
        return f"{self.n_poles}/{self.n_zeros}"

    def to_dict(self) -> dict[str, Any]:
        est = self.estimate
        return {
            "order": self.label,
            "fit_pct": est.fit_pct,
            "validation_fit_pct": None if est.validation is None else est.validation.fit_pct,
            "aic": est.aic,
            "n_params": est.n_model_params,
            "converged": est.converged,
            "warnings": list(est.warnings),
        }


@dataclass(frozen=True)
class OrderSelection:
    """The outcome of :func:`compare_orders`."""

    rows: tuple[OrderRow, ...]
    chosen: int
    rule: str

    @property
    def best(self) -> TFEstimate:
        return self.rows[self.chosen].estimate

    def to_dict(self) -> dict[str, Any]:
        return {
            "chosen": self.rows[self.chosen].label,
            "rule": self.rule,
            "candidates": [r.to_dict() for r in self.rows],
        }


def _contains(big: tuple[int, int], small: tuple[int, int]) -> bool:
    """Whether order ``big`` can reproduce ``small`` (exactly, or with poles far above the band)."""
    return big != small and big[0] >= small[0] and big[1] >= small[1]


def compare_orders(
    estimation: Record,
    orders: Sequence[tuple[int, int]],
    *,
    validation: Record | None = None,
    validation_source: str = "validation",
    max_jitter: float = DEFAULT_MAX_JITTER,
    max_gap: float = DEFAULT_MAX_GAP,
    **tfest_kwargs: Any,
) -> OrderSelection:
    """Estimate each order, score it, and pick one (see the module docstring).

    Parameters
    ----------
    estimation : Record
        Data to estimate from.
    orders : sequence of (int, int)
        Candidate ``(poles, zeros)``.
    validation : Record, optional
        Data to score on; without them the choice is by AIC.
    validation_source : str
        Name of the validation data for reports.
    max_jitter, max_gap : float
        Time-stamp tolerances.
    **tfest_kwargs
        Passed to :func:`gripper_env.sysid.tfest`.
    """
    done: dict[tuple[int, int], TFEstimate] = {}
    for order in sorted(orders, key=lambda o: (o[0] + o[1], o)):
        lower = [done[o] for o in done if _contains(order, o)]
        starts = [min(lower, key=lambda e: float(e.residuals @ e.residuals))] if lower else []
        est = tfest(
            estimation.time_s,
            estimation.u,
            estimation.y,
            order[0],
            order[1],
            r=estimation.r,
            start_from=starts,
            max_jitter=max_jitter,
            max_gap=max_gap,
            **tfest_kwargs,
        )
        if validation is not None:
            fit = validate(
                est, validation, validation_source, max_jitter=max_jitter, max_gap=max_gap
            )
            est = dataclasses.replace(est, validation=fit)
        done[order] = est
    rows = tuple(OrderRow(o[0], o[1], done[o]) for o in orders)
    chosen, rule = choose_order(
        n_params=[r.estimate.n_model_params for r in rows],
        converged=[r.estimate.converged for r in rows],
        aic=[r.estimate.aic for r in rows],
        validation_fit_pct=None if validation is None else [
            _validation_fit_pct(r.estimate) for r in rows
        ],
    )  # fmt: skip
    return OrderSelection(rows, chosen, rule)


def choose_order(
    *,
    n_params: Sequence[int],
    converged: Sequence[bool],
    aic: Sequence[float],
    validation_fit_pct: Sequence[float] | None,
) -> tuple[int, str]:
    """The order selection rule of the module docstring, on each candidate's figures.

    Parameters
    ----------
    n_params : sequence of int
        Model parameters of each candidate.
    converged : sequence of bool
        Whether each candidate's output-error search converged.
    aic : sequence of float
        Akaike's criterion of each candidate.
    validation_fit_pct : sequence of float, optional
        Fit (%) of each candidate on validation data; without it the choice is by AIC.

    Returns
    -------
    index : int
        The chosen candidate.
    rule : str
        The rule as a report states it.
    """
    eligible = [i for i, ok in enumerate(converged) if ok] or list(range(len(converged)))
    if validation_fit_pct is not None:
        fits = list(validation_fit_pct)
        best_fit = max(fits[i] for i in eligible)
        near = [i for i in eligible if fits[i] >= best_fit - FIT_TOLERANCE_PCT]
        chosen = min(near, key=lambda i: (n_params[i], -fits[i]))
        rule = (
            f"highest fit on validation data, the fewest parameters within "
            f"{FIT_TOLERANCE_PCT:g} points of it"
        )
    else:
        chosen = min(eligible, key=lambda i: aic[i])
        rule = "smallest AIC (no validation data)"
    if len(eligible) < len(converged):
        rule += "; orders that did not converge are not chosen"
    return chosen, rule


def _validation_fit_pct(estimate: TFEstimate) -> float:
    """Fit % of an estimate on the validation data (scored whenever validation data is given)."""
    if estimate.validation is None:
        raise ValueError("estimate has no fit on validation data")
    return estimate.validation.fit_pct


def as_record(
    time_s: float | ArrayLike, u: ArrayLike, y: ArrayLike, r: ArrayLike | None = None
) -> Record:
    """A :class:`Record` from arrays."""
    # a scalar sample interval is checked (with a message naming it) when the record is used
    t: Any = time_s if np.ndim(time_s) == 0 else np.asarray(time_s, dtype=float)
    return Record(
        t,
        np.asarray(u, dtype=float),
        np.asarray(y, dtype=float),
        None if r is None else np.asarray(r, float),
    )
