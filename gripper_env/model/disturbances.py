"""The "actual gripper": everything between the controller and the identified transfer function.

A :class:`Disturbance` is a stack of blocks, each with documented units and defaults::

    controller output u (deg)
      -> command   : servo command range, quantisation (1 deg like Servo.write, or the
                     microsecond pulse width), the 20 ms servo refresh (held command), rate limit
      -> friction  : stiction (Choudhury S/J, or the Kano-type force-balance form), backlash
      -> plant TF  : the identified transfer function (zero-order hold at 1 ms)
      -> mechanics : mechanical stops (21, 92 deg) and an optional object in the jaws
      -> sensor    : potentiometer through a 10-bit ADC over its calibrated range, Gaussian
                     noise, delay
    measured angle y (deg)

Presets live in ``configs/disturbances/``: ``ideal`` (the transfer function alone, the paper's
"model"), ``actual`` (a realistic default that shows stick-slip on the 60 s slope) and ``worn``
(heavy friction). A preset may ``extend`` another and override some keys. Any numeric parameter can
be randomised per episode: ``randomize: {"friction.S_deg": [1.0, 3.0]}`` draws it uniformly from
that range with the episode's seeded generator (:meth:`Disturbance.sample`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from gripper_env.io.config import ConfigError, available, find_config, load_yaml, validate

__all__ = [
    "CommandPath",
    "Disturbance",
    "Friction",
    "Mechanics",
    "Sensor",
    "available_disturbances",
    "load_disturbance",
]

_STRICT = ConfigDict(extra="forbid", validate_assignment=True)


class CommandPath(BaseModel):
    """How the controller's output reaches the servo.

    Attributes
    ----------
    range_deg : (float, float)
        Range of angles the servo accepts (deg); commands are clamped to it.
    quantization : {"none", "degree", "microseconds"}
        ``degree``: whole degrees, like Arduino's ``Servo.write``; ``microseconds``: the pulse
        width in whole microseconds over ``pulse_range_us`` for 0-180 deg (about 0.1 deg).
    pulse_range_us : (float, float)
        Pulse widths (us) for 0 and 180 deg, used by ``microseconds`` quantisation.
    refresh_period_s : float
        The servo sees a new command only this often (s); in between it holds the last one.
        Hobby servos refresh at 50 Hz (0.020 s). Rounded to a whole number of physics steps.
    rate_limit_deg_s : float
        Largest change of the command per second (deg/s); 0 for none.
    """

    model_config = _STRICT

    range_deg: tuple[float, float] = (-math.inf, math.inf)
    quantization: Literal["none", "degree", "microseconds"] = "none"
    pulse_range_us: tuple[float, float] = (544.0, 2400.0)
    refresh_period_s: float = Field(0.0, ge=0.0, le=1.0)
    rate_limit_deg_s: float = Field(0.0, ge=0.0)

    @property
    def quantum_deg(self) -> float:
        """Command resolution (deg); 0 for none."""
        if self.quantization == "degree":
            return 1.0
        if self.quantization == "microseconds":
            return 180.0 / (self.pulse_range_us[1] - self.pulse_range_us[0])
        return 0.0


class Friction(BaseModel):
    """Friction of the jaw mechanism (see :mod:`gripper_env.sim.friction`).

    Attributes
    ----------
    model : {"none", "choudhury", "kano"}
        Stiction model.
    S_deg : float
        Deadband plus stickband (deg).
    J_deg : float
        Slip jump (deg).
    backlash_deg : float
        Play of the gear train (deg); 0 for none.
    """

    model_config = _STRICT

    model: Literal["none", "choudhury", "kano"] = "none"
    S_deg: float = Field(0.0, ge=0.0)
    J_deg: float = Field(0.0, ge=0.0)
    backlash_deg: float = Field(0.0, ge=0.0)


class Mechanics(BaseModel):
    """Mechanical limits of the jaw, and how hard the servo pushes against them.

    Attributes
    ----------
    limits_deg : (float, float) or None
        Mechanical stops (closed, open) in deg; ``null`` for none (the linear model alone). The
        paper commands 21 and 92 deg and saw overshoot on the real gripper (its Figure 11a), so
        the stops lie beyond those angles; where exactly is not published (see the presets).
    object_contact_deg : float or None
        An object held in the jaws: closing stops at this angle (deg) while the command may keep
        pushing further, which winds up an integrator (a windup test). ``null`` for no object.
    stall_band_deg : float
        The servo's proportional band (deg): held against a stop or an object, its internal
        position loop drives the motor with a torque that grows with how far the command lies
        beyond the jaw, reaching full (stall) current at this distance. A hobby servo's band is
        a few degrees. The simulation counts *stall* time (command at least this far beyond a
        stop or object the jaw touches) and a *force proxy* (the push as a fraction of stall
        torque, ``min(push / stall_band_deg, 1)``).
    """

    model_config = _STRICT

    limits_deg: tuple[float, float] | None = None
    object_contact_deg: float | None = None
    stall_band_deg: float = Field(5.0, gt=0.0)

    @field_validator("limits_deg")
    @classmethod
    def _ordered(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and not v[0] < v[1]:
            raise ValueError(f"must be [closed_deg, open_deg] with closed < open, got {list(v)}")
        return v


class Sensor(BaseModel):
    """The potentiometer and the Arduino's ADC.

    Attributes
    ----------
    adc_bits : int
        ADC resolution (bits); 0 for an ideal, unquantised measurement.
    adc_range_deg : (float, float)
        Angles (deg) read as ADC count 0 and as the full-scale count (calibrated range).
    noise_std_deg : float
        Standard deviation of additive Gaussian noise before quantisation (deg).
    delay_s : float
        Measurement delay (s), rounded to whole physics steps.
    """

    model_config = _STRICT

    adc_bits: int = Field(0, ge=0, le=24)
    adc_range_deg: tuple[float, float] = (0.0, 270.0)
    noise_std_deg: float = Field(0.0, ge=0.0)
    delay_s: float = Field(0.0, ge=0.0, le=1.0)

    @property
    def lsb_deg(self) -> float:
        """Angle per ADC count (deg); 0 without quantisation."""
        if self.adc_bits == 0:
            return 0.0
        return (self.adc_range_deg[1] - self.adc_range_deg[0]) / (2**self.adc_bits - 1)


_BLOCKS: dict[str, type[BaseModel]] = {
    "command": CommandPath,
    "friction": Friction,
    "mechanics": Mechanics,
    "sensor": Sensor,
}


class Disturbance(BaseModel):
    """A complete actual-gripper model: blocks plus per-episode randomisation ranges.

    Attributes
    ----------
    name : str
        Preset name.
    description : str
        Free text.
    command, friction, mechanics, sensor
        The blocks (see their classes).
    randomize : dict of str to (float, float)
        ``"block.parameter": [low, high]``: draw that parameter uniformly per episode. One entry
        of a pair is ``"block.parameter.0"`` or ``".1"`` (``"mechanics.limits_deg.0"``: the
        closed stop).
    """

    model_config = _STRICT

    name: str = "custom"
    description: str = ""
    command: CommandPath = CommandPath()
    friction: Friction = Friction()
    mechanics: Mechanics = Mechanics()
    sensor: Sensor = Sensor()
    randomize: dict[str, tuple[float, float]] = {}

    @model_validator(mode="after")
    def _check_randomize(self) -> Disturbance:
        for key, (lo, hi) in self.randomize.items():
            block, param, index = _split_key(key)
            if block not in _BLOCKS or param not in _BLOCKS[block].model_fields:
                raise ValueError(
                    f"randomize: unknown parameter {key!r}; use 'block.parameter' (or "
                    f"'block.parameter.0' for one entry of a pair) with block one of "
                    f"{sorted(_BLOCKS)}"
                )
            value = getattr(getattr(self, block), param)
            if index is not None:
                if not isinstance(value, tuple) or not 0 <= index < len(value):
                    raise ValueError(
                        f"randomize: {key!r}: parameter '{block}.{param}' has no entry {index}"
                    )
                value = value[index]
            if not isinstance(value, int | float) or isinstance(value, bool):
                raise ValueError(f"randomize: parameter {key!r} is not a number")
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(f"randomize: range for {key!r} must be [low, high], got {lo, hi}")
        return self

    @property
    def friction_band_deg(self) -> float:
        """Widest band (deg) in which friction may leave the jaw stuck: the largest stiction
        band ``S`` the preset (or its randomisation) can draw, plus the largest backlash; 0 for
        a friction-free model. Settling bands narrower than this measure the friction draw,
        not the controller."""
        f = self.friction

        def widest(name: str) -> float:
            value = getattr(f, name)
            lo_hi = self.randomize.get(f"friction.{name}")
            return max(value, lo_hi[1]) if lo_hi is not None else value

        stiction = widest("S_deg") if f.model != "none" else 0.0
        return float(stiction + widest("backlash_deg"))

    def sample(self, rng: np.random.Generator) -> Disturbance:
        """Draw one episode's parameters from the ``randomize`` ranges.

        Parameters
        ----------
        rng : numpy.random.Generator
            The episode's seeded generator.

        Returns
        -------
        Disturbance
            A copy with concrete values and no ``randomize`` entries.
        """
        if not self.randomize:
            return self
        blocks = {b: getattr(self, b).model_dump() for b in _BLOCKS}
        for key in sorted(self.randomize):
            lo, hi = self.randomize[key]
            block, param, index = _split_key(key)
            value = rng.uniform(lo, hi)
            if index is None:
                if isinstance(blocks[block][param], int):
                    value = round(value)
                blocks[block][param] = value
            else:
                pair = list(blocks[block][param])
                pair[index] = value
                blocks[block][param] = tuple(pair)
        return validate(
            Disturbance,
            {"name": self.name, "description": self.description, **blocks},
            f"disturbance {self.name!r} randomised",
        )

    def with_overrides(self, overrides: Mapping[str, Any]) -> Disturbance:
        """Copy with some blocks' keys replaced: ``{"friction": {"S_deg": 4.0}}``."""
        data = self.model_dump()
        _deep_update(data, dict(overrides))
        return validate(Disturbance, data, f"disturbance {self.name!r} overrides")


def _split_key(key: str) -> tuple[str, str, int | None]:
    """``"block.param"`` -> (block, param, None); ``"block.param.1"`` -> (block, param, 1)."""
    block, _, rest = key.partition(".")
    param, _, index = rest.partition(".")
    return block, param, int(index) if index.isdigit() else (None if index == "" else -1)


def _deep_update(base: dict[str, Any], new: Mapping[str, Any]) -> None:
    for key, value in new.items():
        if isinstance(value, Mapping) and isinstance(base.get(key), dict):
            _deep_update(base[key], value)
        else:
            base[key] = value


def available_disturbances() -> list[str]:
    """Names of the presets in ``configs/disturbances``."""
    return available("disturbances")


def load_disturbance(
    disturbance: str | os.PathLike[str] | Mapping[str, Any] | Disturbance = "actual",
) -> Disturbance:
    """Load a preset by name (``"actual"``), from a YAML path, or from a dict.

    A file or dict may say ``extends: <preset>`` to start from another preset and override keys.

    Raises
    ------
    gripper_env.io.config.ConfigError
        Unknown preset (listing the available ones), missing file, unknown key, or a value out of
        range; the message names the file and the key.
    """
    if isinstance(disturbance, Disturbance):
        return disturbance
    if isinstance(disturbance, Mapping):
        return _from_mapping(dict(disturbance), "disturbance dict", depth=0)
    path = find_config("disturbances", disturbance)
    return _from_mapping(load_yaml(path), str(path), depth=0)


def _from_mapping(data: dict[str, Any], source: str, depth: int) -> Disturbance:
    parent = data.pop("extends", None)
    if parent is None:
        return validate(Disturbance, data, source)
    if depth > 8:
        raise ConfigError(f"{source}: 'extends' chain is too deep (a cycle?)")
    path = find_config("disturbances", str(parent))
    base = _from_mapping(load_yaml(path), str(path), depth + 1).model_dump()
    _deep_update(base, data)
    return validate(Disturbance, base, source)


def describe(d: Disturbance) -> str:
    """One line per block, for reports."""
    c, f, m, s = d.command, d.friction, d.mechanics, d.sensor
    return "\n".join(
        [
            f"command: range {list(c.range_deg)} deg, quantisation {c.quantization}, "
            f"refresh {c.refresh_period_s * 1e3:g} ms, rate limit {c.rate_limit_deg_s:g} deg/s",
            f"friction: {f.model} S={f.S_deg:g} deg J={f.J_deg:g} deg, "
            f"backlash {f.backlash_deg:g} deg",
            f"mechanics: stops {m.limits_deg} deg, object at {m.object_contact_deg}, servo "
            f"stall band {m.stall_band_deg:g} deg",
            f"sensor: {s.adc_bits}-bit ADC over {list(s.adc_range_deg)} deg, "
            f"noise {s.noise_std_deg:g} deg, delay {s.delay_s * 1e3:g} ms",
        ]
    )
