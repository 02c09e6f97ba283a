"""The model: what the paper identified and what the benchmark runs it against.

* :mod:`~gripper_env.model.plants`: the identified transfer functions (Test 1-4, and a user's);
* :mod:`~gripper_env.model.disturbances`: the actual-gripper model's settings (friction, sensor,
  servo, stops) and their randomisation;
* :mod:`~gripper_env.model.references`: reference profiles (steps, ramps, a user's CSV);
* :mod:`~gripper_env.model.pid`: the Simulink-style PID (gains, options, one step);
* :mod:`~gripper_env.model.state_space`: a transfer function as a discrete state-space model.

The model imports only :mod:`gripper_env.io` (configuration files); the simulation core
(:mod:`gripper_env.sim`) runs it.
"""
