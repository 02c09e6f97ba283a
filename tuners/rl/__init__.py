"""Reinforcement learning with stable-baselines3: the RL PID tuner and the RL controller.

* :mod:`~tuners.rl.tune`: the RL PID tuner (PPO on ``GripperPIDTune-v0``, log-gains around a
  textbook design), whose gains file holds the best gains it evaluated;
* :mod:`~tuners.rl.controller`: the RL controller (a residual policy on ``GripperServo-v0``)
  trained and measured over several seeds: validation-selected checkpoints, paired tests
  against its base PID, learning curves, measured margins;
* :mod:`~tuners.rl.policies`: controller policies on the step-by-step environments;
* :mod:`~tuners.rl.agents`: saved agents that rebuild their environment;
* :mod:`~tuners.rl.envs`: the vector environments, the tuner's training reward, progress;
* :mod:`~tuners.rl.report`: what the controller study and ``play`` write and print;
* :mod:`~tuners.rl.command`: ``python -m tuners.rl``.

Nothing here is imported by ``tuners`` itself: the ``rl`` extra (stable-baselines3, torch) is
optional, and :func:`~tuners.rl.envs.require_rl` says in one line how to install it.
"""
