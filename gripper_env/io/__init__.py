"""Files in and out: configuration (:mod:`~gripper_env.io.config`), the records and result files
(:mod:`~gripper_env.io.files`) and the gains file handed from a tuner to a deployment
(:mod:`~gripper_env.model.gains_file`).

The bottom layer: it imports nothing else of the library.
"""
