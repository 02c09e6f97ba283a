"""Reference (desired jaw angle) profiles: the paper's experiments, CSV files and random ones.

Named profiles (all at the 1 ms physics step, angles in deg, 92 = open/un-grip, 21 = closed/grip):

=========  ===================================================================================
``step``   hold 92 for 1 s, grip step to 21, hold 9 s, un-grip step to 92, hold 10 s (20 s)
``slope60``  hold 92 for 1 s, ramp to 21 over 60 s, hold 5 s, ramp to 92 over 60 s, hold 5 s
``slope40``  the same with 40 s ramps
``slope20``  the same with 20 s ramps
``ramp3``  the paper's Figure 2: hold 92 for 1 s, ramp to 21 over 3 s, hold 4 s (8 s)
=========  ===================================================================================

The paper does not publish the exact timing of its profiles; these are documented choices.
A profile may also come from a CSV file (columns ``t_s`` and ``reference_deg`` or
``desired_deg``; resampled to the physics step by linear interpolation) or be drawn at random
(:func:`random_profile`, seeded) for training.
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gripper_env.io.config import MAX_DATA_BYTES, read_bounded

__all__ = [
    "MAX_STEPS_PER_RUN",
    "PROFILES",
    "PROFILE_ABOUT",
    "Reference",
    "Segment",
    "check_steps",
    "describe_profile",
    "load_reference",
    "ramp_profile",
    "random_profile",
    "step_profile",
]

OPEN_DEG = 92.0
CLOSED_DEG = 21.0

#: Most physics steps one run may take: 1000 s at the paper's 1 ms step, or the longest named
#: profile (``slope60``, 131 s) down to a step of 0.131 ms. A run's trajectories take about
#: 1 kB per step in an evaluation (10 seeds, the ideal model, the other identifications), so the
#: bound keeps one run near 1 GB; a tiny ``dt_s`` is refused before anything is allocated.
MAX_STEPS_PER_RUN = 1_000_000


def check_steps(what: str, duration_s: float, dt_s: float) -> int:
    """The number of physics steps of ``duration_s`` at ``dt_s``, refused above
    :data:`MAX_STEPS_PER_RUN`.

    Parameters
    ----------
    what : str
        What lasts ``duration_s`` (``"reference 'step'"``), for the message.
    duration_s, dt_s : float
        Duration and physics step (s).

    Raises
    ------
    ValueError
        Too many steps; the message says which ``dt_s`` would do.
    """
    steps = duration_s / dt_s
    if not steps <= MAX_STEPS_PER_RUN:  # also NaN and inf
        raise ValueError(
            f"{what} lasts {duration_s:g} s: at the plant's dt_s = {dt_s:g} s a run would take "
            f"{steps:.3g} physics steps, more than the {MAX_STEPS_PER_RUN:,} allowed; use a plant "
            f"with dt_s >= {duration_s / MAX_STEPS_PER_RUN:.2g} s (its file's 'dt_s') or a "
            "shorter reference"
        )
    return round(steps)


@dataclass(frozen=True)
class Segment:
    """One grip or un-grip move of a reference, for step metrics.

    Attributes
    ----------
    start, stop : int
        Sample indices: the move starts at ``start``; the segment (move plus hold) ends before
        ``stop``.
    initial_deg, final_deg : float
        Reference before and after the move (deg).
    kind : {"grip", "ungrip"}
        ``grip`` closes (angle decreases), ``ungrip`` opens.
    """

    start: int
    stop: int
    initial_deg: float
    final_deg: float

    @property
    def kind(self) -> str:
        return "grip" if self.final_deg < self.initial_deg else "ungrip"


@dataclass(frozen=True)
class Reference:
    """A sampled reference profile.

    Attributes
    ----------
    name : str
        Profile name.
    dt_s : float
        Sample time (s).
    values_deg : ndarray, shape (T,)
        Desired jaw angle at each sample (deg).
    segments : tuple of Segment
        Grip and un-grip moves, in time order.
    """

    name: str
    dt_s: float
    values_deg: np.ndarray
    segments: tuple[Segment, ...] = field(default_factory=tuple)

    @property
    def t_s(self) -> np.ndarray:
        """Sample times (s)."""
        return np.arange(len(self.values_deg)) * self.dt_s

    @property
    def duration_s(self) -> float:
        return len(self.values_deg) * self.dt_s

    def __len__(self) -> int:
        return len(self.values_deg)


def _build(name: str, dt_s: float, pieces: list[tuple[float, float, float]]) -> Reference:
    """Concatenate ``(duration_s, start_deg, end_deg)`` pieces (a hold has start == end)."""
    check_steps(f"reference {name!r}", sum(p[0] for p in pieces), dt_s)
    values: list[np.ndarray] = []
    moves: list[tuple[int, float, float]] = []
    n0 = 0
    for duration, a, b in pieces:
        n = round(duration / dt_s)
        if n <= 0:
            continue
        if a == b:
            values.append(np.full(n, a))
        else:
            # ramp: the first sample already moves, the last reaches the end value
            values.append(a + (b - a) * np.arange(1, n + 1) / n)
            moves.append((n0, a, b))
        n0 += n
    r = np.concatenate(values)
    segments = []
    for i, (start, a, b) in enumerate(moves):
        stop = moves[i + 1][0] if i + 1 < len(moves) else len(r)
        segments.append(Segment(start, stop, a, b))
    return Reference(name, dt_s, r, tuple(segments))


def step_profile(
    dt_s: float = 1e-3, hold_s: float = 1.0, grip_s: float = 9.0, ungrip_s: float = 10.0
) -> Reference:
    """Grip step 92 -> 21 after ``hold_s``, un-grip step 21 -> 92 after ``grip_s`` more."""
    check_steps("reference 'step'", hold_s + grip_s + ungrip_s, dt_s)
    n_hold = round(hold_s / dt_s)
    n_grip = round(grip_s / dt_s)
    n_ungrip = round(ungrip_s / dt_s)
    r = np.concatenate(
        [np.full(n_hold, OPEN_DEG), np.full(n_grip, CLOSED_DEG), np.full(n_ungrip, OPEN_DEG)]
    )
    segs = (
        Segment(n_hold, n_hold + n_grip, OPEN_DEG, CLOSED_DEG),
        Segment(n_hold + n_grip, len(r), CLOSED_DEG, OPEN_DEG),
    )
    return Reference("step", dt_s, r, segs)


def ramp_profile(ramp_s: float, dt_s: float = 1e-3, hold_s: float = 5.0) -> Reference:
    """Ramp 92 -> 21 over ``ramp_s``, hold ``hold_s``, ramp back, hold (after 1 s at 92)."""
    return _build(
        f"slope{ramp_s:g}",
        dt_s,
        [
            (1.0, OPEN_DEG, OPEN_DEG),
            (ramp_s, OPEN_DEG, CLOSED_DEG),
            (hold_s, CLOSED_DEG, CLOSED_DEG),
            (ramp_s, CLOSED_DEG, OPEN_DEG),
            (hold_s, OPEN_DEG, OPEN_DEG),
        ],
    )


def _ramp3(dt_s: float) -> Reference:
    ref = _build(
        "ramp3",
        dt_s,
        [(1.0, OPEN_DEG, OPEN_DEG), (3.0, OPEN_DEG, CLOSED_DEG), (4.0, CLOSED_DEG, CLOSED_DEG)],
    )
    return ref


PROFILES = {
    "step": lambda dt_s: step_profile(dt_s),
    "slope60": lambda dt_s: ramp_profile(60.0, dt_s),
    "slope40": lambda dt_s: ramp_profile(40.0, dt_s),
    "slope20": lambda dt_s: ramp_profile(20.0, dt_s),
    "ramp3": _ramp3,
}

#: What each named profile is, in a line (``gripper list profiles``; the module docstring).
PROFILE_ABOUT = {
    "step": "hold 92 deg 1 s, grip step to 21, hold 9 s, un-grip step to 92, hold 10 s (20 s)",
    "slope60": "hold 92 deg 1 s, ramp to 21 over 60 s, hold 5 s, ramp back over 60 s, hold 5 s",
    "slope40": "the same with 40 s ramps",
    "slope20": "the same with 20 s ramps",
    "ramp3": "the paper's Figure 2: hold 92 deg 1 s, ramp to 21 over 3 s, hold 4 s (8 s)",
}


def describe_profile(name: str) -> str:
    """A named profile in a line (:data:`PROFILE_ABOUT`)."""
    return PROFILE_ABOUT.get(name, "")


def random_profile(
    rng: np.random.Generator | int | None,
    duration_s: float = 20.0,
    dt_s: float = 1e-3,
    jaw_range_deg: tuple[float, float] = (CLOSED_DEG, OPEN_DEG),
    ramp_probability: float = 0.4,
) -> Reference:
    """A seeded random sequence of grip and un-grip moves, for training.

    Starts open (at the top of ``jaw_range_deg``) for 0.5-1.5 s, then alternates grip and un-grip
    moves to random targets (at least 10 % of the range each), each a step or (with
    ``ramp_probability``) a ramp of 0.2-5 s, followed by a hold of 1-5 s.

    Parameters
    ----------
    rng : numpy.random.Generator or int or None
        Generator or seed.
    duration_s : float
        Length of the profile (s).
    """
    check_steps("a random reference", duration_s, dt_s)
    rng = np.random.default_rng(rng)
    lo, hi = jaw_range_deg
    span = hi - lo
    pieces: list[tuple[float, float, float]] = [(rng.uniform(0.5, 1.5), hi, hi)]
    total = pieces[0][0]
    here = hi
    closing = True
    while total < duration_s:
        if closing:
            target = rng.uniform(lo, here - 0.1 * span) if here - 0.1 * span > lo else lo
        else:
            target = rng.uniform(here + 0.1 * span, hi) if here + 0.1 * span < hi else hi
        target = float(np.round(target, 1))
        if rng.random() < ramp_probability:
            ramp = rng.uniform(0.2, 5.0)
            pieces.append((ramp, here, target))
            total += ramp
        else:
            pieces.append((dt_s, here, target))
            total += dt_s
        hold = rng.uniform(1.0, 5.0)
        pieces.append((hold, target, target))
        total += hold
        here = target
        closing = not closing
    ref = _build("random", dt_s, pieces)
    n = round(duration_s / dt_s)
    values = ref.values_deg[:n]
    segs = tuple(
        Segment(s.start, min(s.stop, n), s.initial_deg, s.final_deg)
        for s in ref.segments
        if s.start < n - 1
    )
    return Reference("random", dt_s, values, segs)


def _from_csv(path: Path, dt_s: float) -> Reference:
    text = read_bounded(path, MAX_DATA_BYTES, "reference CSV")
    try:
        rows = list(csv.DictReader(io.StringIO(text.decode("utf-8-sig"), newline="")))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ValueError(f"cannot read reference CSV {path}: {exc}") from None
    if not rows:
        raise ValueError(f"reference CSV {path} has no data rows")
    columns = rows[0].keys()
    value_col = next((c for c in ("reference_deg", "desired_deg") if c in columns), None)
    if "t_s" not in columns or value_col is None:
        raise ValueError(
            f"reference CSV {path} needs columns 't_s' and 'reference_deg' (or 'desired_deg'); "
            f"found {list(columns)}"
        )
    try:
        t = np.array([float(r["t_s"]) for r in rows])
        v = np.array([float(r[value_col]) for r in rows])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"reference CSV {path}: non-numeric value ({exc})") from None
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
        raise ValueError(f"reference CSV {path}: non-finite values")
    if len(t) < 2 or np.any(np.diff(t) <= 0):
        raise ValueError(f"reference CSV {path}: t_s must be strictly increasing, >= 2 rows")
    check_steps(f"reference CSV {str(path)!r}", float(t[-1] - t[0]), dt_s)
    grid = np.arange(t[0], t[-1] + dt_s / 2, dt_s)
    values = np.interp(grid, t, v)
    return Reference(path.stem, dt_s, values, _detect_segments(values))


def _detect_segments(values: np.ndarray, min_move_deg: float = 1.0) -> tuple[Segment, ...]:
    """Find monotone moves of at least ``min_move_deg`` between holds."""
    dv = np.diff(values)
    moving = np.abs(dv) > 1e-9
    segs: list[tuple[int, int, float, float]] = []
    i = 0
    n = len(dv)
    while i < n:
        if not moving[i]:
            i += 1
            continue
        direction = np.sign(dv[i])
        j = i
        while j < n and moving[j] and np.sign(dv[j]) == direction:
            j += 1
        a, b = values[i], values[j]
        if abs(b - a) >= min_move_deg:
            segs.append((i + 1, j + 1, float(a), float(b)))
        i = j
    out = []
    for k, (start, _end, a, b) in enumerate(segs):
        stop = segs[k + 1][0] if k + 1 < len(segs) else len(values)
        out.append(Segment(start, stop, a, b))
    return tuple(out)


def load_reference(reference: str | os.PathLike[str] | Reference, dt_s: float = 1e-3) -> Reference:
    """A named profile (see the module docstring), a CSV path, or a :class:`Reference` as is.

    Raises
    ------
    ValueError
        Unknown name (listing the names), a malformed or too large CSV file, or a run of more
        than :data:`MAX_STEPS_PER_RUN` physics steps at ``dt_s``.
    """
    if isinstance(reference, Reference):
        return reference
    text = os.fspath(reference)
    if text in PROFILES:
        return PROFILES[text](dt_s)
    path = Path(text)
    if path.suffix.lower() == ".csv":
        if path.is_dir():
            raise ValueError(f"reference CSV {text!r} is a folder; give a CSV file")
        if not path.is_file():
            raise ValueError(f"reference CSV {text!r} does not exist")
        return _from_csv(path, dt_s)
    raise ValueError(
        f"unknown reference profile {text!r}; available: {', '.join(PROFILES)}, or a .csv file"
    )
