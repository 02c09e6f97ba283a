"""Figures of the bus-servo commands: register sets on tracking and grasp-and-hold, and a
deploy's measured response against the model's prediction."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from gripper_env.evaluation.bus_servo import (
    HOLD_FORCE_FRAC,
    BusScore,
    hold_goal,
    tracking_goal,
)
from gripper_env.io.files import save_figure
from gripper_env.model.bus_servo import BusServoModel
from gripper_env.sim.bus_servo import DT, simulate_bus

__all__ = ["plot_deploy", "plot_registers"]


def plot_registers(
    model: BusServoModel, rows: Mapping[str, BusScore], path: str | os.PathLike[str]
) -> Path:
    """Tracking (angle and duty) and grasp-and-hold (force, trips) of each register set."""
    names = list(rows)
    regs = [rows[n].registers for n in names]
    goal, _ = tracking_goal(model)
    track = simulate_bus(model, regs, goal)
    hgoal = hold_goal(model)
    hold = simulate_bus(model, regs, hgoal, with_object=True)
    fig, ax = plt.subplots(2, 2, figsize=(12, 7), sharex="col")
    t1 = np.arange(goal.size) * DT
    t2 = np.arange(hgoal.size) * DT
    ax[0, 0].plot(t1, goal, "k--", lw=1, label="goal")
    stall = model.stall_force_n()
    for i, name in enumerate(names):
        label = f"{name}: {regs[i].label()}"
        ax[0, 0].plot(t1, track.position[i] * model.deg_per_tick, lw=1.2, label=label)
        ax[1, 0].plot(t1, track.duty[i] * 100, lw=0.8)
        ax[0, 1].plot(t2, hold.force[i] * stall, lw=1.2, label=label)
        ax[1, 1].plot(t2, hold.temperature[i], lw=1.0)
        trips = np.flatnonzero(hold.trip[i] > 0)
        if trips.size:
            ax[0, 1].plot(t2[trips[0]], hold.force[i, trips[0]] * stall, "x", ms=9, color=f"C{i}")
    ax[0, 1].axhline(HOLD_FORCE_FRAC * stall, color="k", ls=":", lw=1, label="required force")
    ax[1, 1].axhline(model.protection.max_temp_c, color="r", ls=":", lw=1, label="thermal cut-out")
    ax[0, 0].set_ylabel("jaw angle (deg)")
    ax[1, 0].set_ylabel("duty (%)")
    ax[0, 1].set_ylabel("grip force (N)")
    ax[1, 1].set_ylabel("winding temperature (C)")
    ax[1, 0].set_xlabel("time (s)")
    ax[1, 1].set_xlabel("time (s)")
    ax[0, 0].set_title(f"{model.name}: tracking, free jaw")
    ax[0, 1].set_title(f"grasp at {model.jaw.object_deg:g} deg and hold (x: protection trips)")
    ax[0, 0].legend(fontsize=7)
    ax[0, 1].legend(fontsize=7)
    ax[1, 1].legend(fontsize=7)
    for a in ax.ravel():
        a.grid(alpha=0.3)
    fig.tight_layout()
    out = save_figure(fig, path)
    plt.close(fig)
    return out


def plot_deploy(
    t_s: np.ndarray,
    goal_deg: np.ndarray,
    measured_deg: np.ndarray,
    predicted_deg: np.ndarray,
    title: str,
    path: str | os.PathLike[str],
) -> Path:
    """A deploy's verification: the goal, the measured jaw and the model's prediction."""
    fig, ax = plt.subplots(figsize=(9, 4))
    ax.plot(t_s, goal_deg, "k--", lw=1, label="goal")
    ax.plot(t_s, predicted_deg, lw=1.5, label="model prediction")
    ax.plot(t_s, measured_deg, ".", ms=3, label="measured (bus)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("jaw angle (deg)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    out = save_figure(fig, path)
    plt.close(fig)
    return out
