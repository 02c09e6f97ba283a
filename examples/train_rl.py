"""Train a stable-baselines3 PPO agent on a registered gripper environment, and evaluate it.

Needs the ``rl`` extra (``pip install -e ".[rl]"``: stable-baselines3 and a CPU build of torch).

``gripper_env/GripperServo-v0`` makes the agent the controller: every 20 ms it sets the servo
command, the simulated actual gripper runs at 1 ms in between, and the reward penalises the
tracking error over the paper's 20 s grip/un-grip step. With ``--residual reference`` (the
default here) the action is a bounded correction added to the reference, so the zero action
is "command = reference" and a short training run starts from a sensible policy; ``--residual
none`` leaves the agent the whole command range.

The agent is evaluated beside the zero action and uniformly random actions, two ways: the
return of whole episodes of the environment (a plain Gymnasium loop), and the same episodes
replayed from their ``info["noise_seed"]`` as trajectories
(:func:`gripper_env.envs.rollout.policy_trajectory`), scored with the metrics every PID tuner is
scored with. A random policy leaves the jaw swinging, which the metrics score as
unstable (IAE ``inf``).

Run::

    python examples/train_rl.py                       # 8192 steps, about 15 s
    python examples/train_rl.py --timesteps 200000    # a few minutes; see docs/envs.md

For real training use the native vector environment (:class:`gripper_env.envs.sb3.NativeVecEnv`,
one compiled call for all environments) and ``VecNormalize``, as in ``docs/envs.md``, or
``python -m tuners.rl``.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import gripper_env  # noqa: F401  (registers the environments)
from gripper_env.envs.rollout import policy_trajectory
from gripper_env.evaluation.metrics import compute_metrics

ENV_ID = "gripper_env/GripperServo-v0"


def episode_return(env: gym.Env, policy, seed: int) -> tuple[float, int]:
    """Sum of rewards of one whole episode of ``policy`` (a batch of observations -> actions),
    and the episode's disturbance seed (``info["noise_seed"]``, which replays it)."""
    obs, info = env.reset(seed=seed)
    total, done = 0.0, False
    while not done:
        action = policy(obs[None, :])[0]
        obs, reward, terminated, truncated, _ = env.step(action)
        total += float(reward)
        done = terminated or truncated
    return total, int(info["noise_seed"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=8192, help="PPO steps (default: 8192)")
    parser.add_argument(
        "--residual", choices=("reference", "none"), default="reference",
        help="action: a correction to the reference (default), or the whole command",
    )  # fmt: skip
    parser.add_argument("--plant", default="test2", help="plant (default: test2)")
    parser.add_argument("--seed", type=int, default=0, help="training seed (default: 0)")
    parser.add_argument("--episodes", type=int, default=3, help="evaluation episodes (default 3)")
    args = parser.parse_args(argv)

    import torch  # the rl extra
    from stable_baselines3 import PPO

    torch.set_num_threads(1)  # small networks: one thread is fastest
    env_kwargs = {"plant": args.plant}
    if args.residual != "none":
        env_kwargs["residual"] = args.residual
    env = gym.make(ENV_ID, **env_kwargs)
    model = PPO(
        "MlpPolicy", env, n_steps=256, batch_size=64, n_epochs=4, gamma=0.98, seed=args.seed,
        device="cpu", policy_kwargs={"net_arch": [32, 32], "log_std_init": -2.0},
    )  # fmt: skip
    start = time.perf_counter()
    model.learn(total_timesteps=args.timesteps)
    print(
        f"trained PPO on {ENV_ID} ({args.plant}, residual {args.residual}) for "
        f"{model.num_timesteps} steps in {time.perf_counter() - start:.1f} s"
    )

    # Evaluation episodes, on reset seeds apart from training's.
    rng = np.random.default_rng(args.seed)
    policies = {
        "PPO": lambda obs: model.predict(obs, deterministic=True)[0],
        "zero action": lambda obs: np.zeros((len(obs), 1), np.float32),
        "random actions": lambda obs: rng.uniform(-1, 1, (len(obs), 1)).astype(np.float32),
    }
    for name, policy in policies.items():
        returns, seeds = zip(
            *(episode_return(env, policy, 10_000 + k) for k in range(args.episodes)), strict=True
        )
        # the same episodes (disturbance and noise) as trajectories, in one batch, scored with
        # the metrics of every tuner's PID (on the true jaw angle)
        traj = policy_trajectory(policy, list(seeds), env_id=ENV_ID, **env_kwargs)
        m = compute_metrics(traj, signal="true")
        print(
            f"{name:>14}: return {np.mean(returns):8.1f}, IAE {np.mean(m.run['iae']):7.2f} deg*s, "
            f"stable {int(m.stable.sum())}/{args.episodes}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
