"""Judging a run: what the benchmark and every tuner score a controller by.

* :mod:`~gripper_env.evaluation.metrics`: MATLAB-compatible step metrics, the paper's SD, IAE;
* :mod:`~gripper_env.evaluation.objective`: the tuning objective (``configs/objective.yaml``);
* :mod:`~gripper_env.evaluation.scoring`: one scoring path over the simulation core;
* :mod:`~gripper_env.evaluation.stability`: margins of the sampled-data loop (1 ms PID, 20 ms
  servo hold).

Evaluation imports the model and the simulation core, never the environments or the hardware.
"""
