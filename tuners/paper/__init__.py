"""``python -m tuners.paper``: the paper's tables and figures reproduced
(:mod:`tuners.paper.reproduce`) against its published numbers (:mod:`gripper_env.paper`)."""
