"""The configuration files that ship with gripper-env, installed as ``gripper_env.configs``.

This folder holds data, not code: ``plants/`` (the paper's transfer functions),
``disturbances/`` (actual-gripper presets), ``tuners/`` (tuner and evaluation settings),
``objective.yaml`` and ``benchmark.yaml``. ``pyproject.toml`` maps it into the package
``gripper_env.configs``, so a wheel carries it and :mod:`gripper_env.io.config` reads it with
:mod:`importlib.resources` wherever the package is installed.
"""
