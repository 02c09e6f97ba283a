"""The gripper's identified transfer functions (desired jaw angle -> actual jaw angle).

The paper's four plants live in ``configs/plants/test1.yaml`` ... ``test4.yaml``; a user adds a
plant with a YAML file of coefficients (highest power of ``s`` first):

.. code-block:: yaml

    name: my_gripper
    description: identified from my rig, 60 s slope
    num: [20.7, 0.002852]
    den: [2.0, 20.68, 0.003084]
    fit_pct: 95.33
    dt_s: 0.001
    jaw_range_deg: [21.0, 92.0]

and loads it with ``load_plant("path/to/my_gripper.yaml")``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from gripper_env.io.config import available, find_config, load_yaml, validate
from gripper_env.io.files import safe_name
from gripper_env.model.state_space import observer_form, zoh_matrices

if TYPE_CHECKING:
    import control

__all__ = ["MIN_DT_S", "Plant", "PlantSpec", "available_plants", "load_plant"]

#: Smallest physics step of a plant (s), 1 % of the paper's 1 ms: a finer step resolves nothing
#: the servo's 20 ms frame, the 1 ms board loop or the sensor can show, and a 1e-9 s step would
#: ask for billions of samples per run.
MIN_DT_S = 1e-5


class PlantSpec(BaseModel):
    """Schema of a plant file (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")

    name: str
    description: str = ""
    num: list[float] = Field(description="numerator coefficients, highest power of s first")
    den: list[float] = Field(description="denominator coefficients, highest power of s first")
    fit_pct: float | None = Field(None, description="identification fit (%), MATLAB compare")
    dt_s: float = Field(
        1e-3,
        ge=MIN_DT_S,
        le=0.1,
        description="physics step (s); a run may take at most "
        "gripper_env.model.references.MAX_STEPS_PER_RUN of them",
    )
    jaw_range_deg: tuple[float, float] = (21.0, 92.0)

    @field_validator("name")
    @classmethod
    def _plain_name(cls, v: str) -> str:
        return safe_name(v, "plant name")  # it names the folder of the plant's results

    @field_validator("num", "den")
    @classmethod
    def _finite_nonempty(cls, v: list[float]) -> list[float]:
        if len(v) == 0:
            raise ValueError("must hold at least one coefficient")
        if not all(math.isfinite(c) for c in v):
            raise ValueError(f"coefficients must be finite numbers, got {v}")
        return v

    @field_validator("jaw_range_deg")
    @classmethod
    def _range(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (math.isfinite(v[0]) and math.isfinite(v[1]) and v[0] < v[1]):
            raise ValueError(f"must be [closed_deg, open_deg] with closed < open, got {list(v)}")
        return v

    @model_validator(mode="after")
    def _proper(self) -> PlantSpec:
        num = _strip(self.num)
        den = _strip(self.den)
        if len(den) == 0:
            raise ValueError("den: all coefficients are zero")
        if len(num) == 0:
            raise ValueError("num: all coefficients are zero")
        if len(den) < 2:
            raise ValueError("den: the plant needs at least one pole (order >= 1)")
        if len(num) > len(den):
            raise ValueError(
                f"improper transfer function: numerator order {len(num) - 1} > "
                f"denominator order {len(den) - 1}"
            )
        return self


def _strip(coeffs: list[float]) -> list[float]:
    """Drop leading zeros."""
    i = 0
    while i < len(coeffs) and coeffs[i] == 0.0:
        i += 1
    return list(coeffs[i:])


@dataclass(frozen=True, eq=False)
class Plant:
    """A continuous-time transfer function from desired to actual jaw angle (deg -> deg).

    Parameters
    ----------
    name : str
        Short name (``"test2"``).
    num, den : tuple of float
        Coefficients in ``s`` (highest power first), exactly as written in the file.
    fit_pct : float or None
        Fit (%) that identification reported.
    dt_s : float
        Physics step (s) used for the zero-order-hold discretisation.
    jaw_range_deg : tuple of float
        ``(closed, open)`` mechanical range (deg).
    description : str
        Free text.
    source : str
        File the plant was loaded from.
    """

    name: str
    num: tuple[float, ...]
    den: tuple[float, ...]
    fit_pct: float | None = None
    dt_s: float = 1e-3
    jaw_range_deg: tuple[float, float] = (21.0, 92.0)
    description: str = ""
    source: str = ""

    @classmethod
    def from_spec(cls, spec: PlantSpec, source: str = "") -> Plant:
        """Build a plant from a validated :class:`PlantSpec`."""
        return cls(
            name=spec.name,
            num=tuple(_strip(spec.num)),
            den=tuple(_strip(spec.den)),
            fit_pct=spec.fit_pct,
            dt_s=spec.dt_s,
            jaw_range_deg=spec.jaw_range_deg,
            description=spec.description,
            source=source,
        )

    @classmethod
    def from_coefficients(
        cls, num: list[float], den: list[float], name: str = "custom", **kwargs: object
    ) -> Plant:
        """Validate coefficients (finite, non-empty, proper) and build a plant."""
        spec = validate(PlantSpec, {"name": name, "num": num, "den": den, **kwargs}, name)
        return cls.from_spec(spec, source="<coefficients>")

    @property
    def order(self) -> int:
        """Number of poles."""
        return len(self.den) - 1

    @cached_property
    def tf(self) -> control.TransferFunction:  # python-control loads on first use (1 s)
        """The python-control continuous-time transfer function (s)."""
        import control

        return control.tf(list(self.num), list(self.den))

    def discretize(self, dt_s: float | None = None) -> control.TransferFunction:
        """Exact zero-order-hold discretisation at ``dt_s`` (default: the plant's physics step)."""
        import control

        return control.c2d(self.tf, self.dt_s if dt_s is None else dt_s, method="zoh")

    @cached_property
    def poles(self) -> np.ndarray:
        """Poles (rad/s)."""
        return np.roots(self.den)

    @cached_property
    def zeros(self) -> np.ndarray:
        """Zeros (rad/s)."""
        return np.roots(self.num) if len(self.num) > 1 else np.array([])

    @property
    def dc_gain(self) -> float:
        """Static gain ``G(0)`` (deg/deg); ``inf`` for a plant with a pole at the origin."""
        return self.num[-1] / self.den[-1] if self.den[-1] != 0 else math.inf

    @property
    def is_stable(self) -> bool:
        """All poles strictly in the left half plane."""
        return bool(np.all(self.poles.real < 0))

    def observable_form(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Continuous observable canonical form ``(A, B, D)`` with output ``y = x[0] + D u``.

        The first state is the jaw angle itself, so a mechanical stop clamps one state
        (:func:`gripper_env.model.state_space.observer_form`).
        """
        a, b, _, d = observer_form(self.num, self.den)
        return a, b, d

    def zoh_matrices(self, dt_s: float | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """Discrete ``(Ad, Bd, D)`` of :meth:`observable_form` under a zero-order hold."""
        return zoh_matrices(self.num, self.den, self.dt_s if dt_s is None else dt_s)

    def rest_state(self, y0_deg: float, exact: bool = False) -> tuple[np.ndarray, float]:
        """State and constant input at which the plant rests with output ``y0_deg``.

        Parameters
        ----------
        y0_deg : float
            Jaw angle at rest (deg).
        exact : bool
            ``False`` (default): *quasi-rest* under the input ``u0 = y0`` -- the servo rests
            where it is commanded. Every state derivative but the slowest is zero. The paper's
            plants have gain 1 over seconds and an almost-cancelling slow pole/zero pair (time
            constants up to hours), so this is how a gripper that has just arrived at ``y0``
            starts. ``True``: the true equilibrium under ``u0 = y0 / G(0)``, which for test2
            (``G(0) = 0.925``) means the slow mode has been charged for hours.

        Returns
        -------
        x0 : ndarray
            State of :meth:`observable_form`.
        u0 : float
            The input (deg) that holds it.
        """
        a, b, d = self.observable_form()
        n = a.shape[0]
        g0 = self.dc_gain
        if exact and math.isfinite(g0) and abs(g0) > 1e-12:
            u0 = y0_deg / g0
            return np.linalg.solve(a, -b * u0), float(u0)
        u0 = float(y0_deg)
        x0 = np.zeros(n)
        x0[0] = y0_deg - d * u0
        for i in range(n - 1):
            # derivative of state i is a[i, 0] x0 + x[i+1] + b[i] u0 = 0
            x0[i + 1] = -(a[i, 0] * x0[0] + b[i] * u0)
        return x0, u0

    def __repr__(self) -> str:
        return f"Plant({self.name!r}, num={list(self.num)}, den={list(self.den)})"


def available_plants() -> list[str]:
    """Names of the plants shipped in ``configs/plants``."""
    return available("plants")


def load_plant(plant: str | os.PathLike[str] | Plant) -> Plant:
    """Load a plant by name (``"test2"``) or from a YAML path; a :class:`Plant` passes through.

    Raises
    ------
    gripper_env.io.config.ConfigError
        Unknown name (the message lists the available ones), missing file, or coefficients that
        are empty, non-finite or improper.
    """
    if isinstance(plant, Plant):
        return plant
    path = find_config("plants", plant)
    spec = validate(PlantSpec, load_yaml(path), str(path))
    return Plant.from_spec(spec, source=str(path))
