"""Gymnasium environments of the gripper, registered when :mod:`gripper_env` is imported.

=====================================  =====================================================
id                                     the agent ...
=====================================  =====================================================
``gripper_env/GripperServo-v0``        is the controller: sets the servo command every 20 ms
``gripper_env/GripperPIDTune-v0``      is the tuner: one step = PID gains for a whole episode
``gripper_env/GripperGainSchedule-v0`` schedules the PID's gains every 20 ms
=====================================  =====================================================

``gym.make("gripper_env:gripper_env/GripperServo-v0")`` works without importing the package
first; ``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` gives the
native vector environment (:mod:`gripper_env.envs.vector`). The classes are imported lazily, so
importing :mod:`gripper_env` does not compile the environments' kernels.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "ENV_IDS",
    "GripperGainScheduleEnv",
    "GripperGainScheduleVectorEnv",
    "GripperPIDTuneEnv",
    "GripperPIDTuneVectorEnv",
    "GripperServoEnv",
    "GripperServoVectorEnv",
    "register_envs",
]

#: id -> (entry point, vector entry point, max_episode_steps)
_SPECS: dict[str, tuple[str, str, int]] = {
    "gripper_env/GripperServo-v0": (
        "gripper_env.envs.servo:GripperServoEnv",
        "gripper_env.envs.vector:GripperServoVectorEnv",
        1000,  # 20 s at the 20 ms control period
    ),
    "gripper_env/GripperPIDTune-v0": (
        "gripper_env.envs.pid_tune:GripperPIDTuneEnv",
        "gripper_env.envs.vector:GripperPIDTuneVectorEnv",
        1,  # one step is one whole episode
    ),
    "gripper_env/GripperGainSchedule-v0": (
        "gripper_env.envs.gain_schedule:GripperGainScheduleEnv",
        "gripper_env.envs.vector:GripperGainScheduleVectorEnv",
        1000,
    ),
}
ENV_IDS = tuple(_SPECS)

_LAZY = {
    "GripperServoEnv": "gripper_env.envs.servo",
    "GripperPIDTuneEnv": "gripper_env.envs.pid_tune",
    "GripperGainScheduleEnv": "gripper_env.envs.gain_schedule",
    "GripperServoVectorEnv": "gripper_env.envs.vector",
    "GripperPIDTuneVectorEnv": "gripper_env.envs.vector",
    "GripperGainScheduleVectorEnv": "gripper_env.envs.vector",
}


def register_envs() -> None:
    """Register the environments with Gymnasium (idempotent)."""
    import gymnasium

    for env_id, (entry, vector_entry, max_steps) in _SPECS.items():
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point=entry,
            vector_entry_point=vector_entry,
            max_episode_steps=max_steps,
        )


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
