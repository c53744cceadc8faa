"""Learning to roll the six-bar robot to a goal with a standard library: SBX's PPO (Stable-Baselines3
on JAX) trains on `GoalRollEnv`, the bundled six-bar rover (`SixbarRollEnv`) with the goal drawn
each episode in a random direction and the goal's offset from the robot in the observation, and
the learning curve is written as CSV and PNG (environment steps, wall time, mean return of the
episodes that ended in each logging window). At the end the learned policy and a random one are
evaluated on the same goals and seeds: how often each reaches its goal and in how long.

Not a test and not a test dependency: SBX brings Stable-Baselines3, and with it PyTorch from PyPI
with its CUDA libraries. Here the environment came to 6.2 GB in 221 s (2026-11-29), far beyond
what CI can install. Set up once, with a release build of the package:

    python3 -m venv target/rl-venv
    target/rl-venv/bin/pip install sbx-rl "jax[cpu]" gymnasium matplotlib
    target/rl-venv/bin/pip install './python[gym]'
    target/rl-venv/bin/python benches/learn_roll.py --timesteps 200000 --out target/learn_roll
"""

import argparse
import csv
import os
import sys
import time

import numpy as np

import gymnasium as gym
from tensegrity.envs import SixbarRollEnv


class GoalRollEnv(gym.Wrapper):
    """`SixbarRollEnv` with a goal `distance` m away in a direction drawn from the episode's seed,
    the goal's offset from the struts' centre (m, in the floor's plane) appended to the
    observation, and the reward in cm of progress toward the goal per action."""

    def __init__(self, distance=1.5, action_period=100, max_episode_steps=100, reach=0.25):
        env = SixbarRollEnv(goal=(distance, 0.0), reach=reach, action_period=action_period,
                            max_episode_steps=max_episode_steps)
        super().__init__(env)
        self.distance = float(distance)
        low = np.concatenate([env.observation_space.low, [-np.inf, -np.inf]])
        high = np.concatenate([env.observation_space.high, [np.inf, np.inf]])
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float64)
        self._rng = np.random.default_rng()

    def _offset(self):
        state = self.env.unwrapped._state
        centre = np.mean(np.asarray(state.body_position, dtype=np.float64)[:, :2], axis=0)
        return self.env.unwrapped.goal - centre

    def reset(self, *, seed=None, options=None):
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        angle = self._rng.uniform(0.0, 2.0 * np.pi)
        self.env.unwrapped.goal = self.distance * np.array([np.cos(angle), np.sin(angle)])
        obs, info = self.env.reset(seed=None if seed is None else int(seed), options=options)
        return np.concatenate([obs, self._offset()]), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["reached"] = bool(terminated and self.env.unwrapped._distance <= self.env.unwrapped.reach)
        return np.concatenate([obs, self._offset()]), 100.0 * reward, terminated, truncated, info


def evaluate(policy, episodes, seed, env_kwargs):
    """Success rate and mean time to the goal (s, over the successes) of `policy(obs)`."""
    env = GoalRollEnv(**env_kwargs)
    reached, times = 0, []
    for k in range(episodes):
        obs, _ = env.reset(seed=seed + k)
        for step in range(env_kwargs["max_episode_steps"]):
            obs, _, terminated, truncated, info = env.step(policy(obs))
            if terminated or truncated:
                break
        if info.get("reached"):
            reached += 1
            times.append((step + 1) * env_kwargs["action_period"] * 1e-3)
    env.close()
    return reached / episodes, (float(np.mean(times)) if times else float("nan"))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--timesteps", type=int, default=200_000, help="environment steps (actions) to train")
    p.add_argument("--distance", type=float, default=1.5, help="goal distance, m")
    p.add_argument("--action-period", type=int, default=100, help="physics steps (1 ms) per action")
    p.add_argument("--episode-actions", type=int, default=100)
    p.add_argument("--eval-episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="target/learn_roll")
    args = p.parse_args()
    from sbx import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    os.makedirs(args.out, exist_ok=True)
    env_kwargs = dict(distance=args.distance, action_period=args.action_period,
                      max_episode_steps=args.episode_actions)
    env = gym.wrappers.RecordEpisodeStatistics(GoalRollEnv(**env_kwargs))
    rows, start = [], time.perf_counter()

    class Curve(BaseCallback):
        def __init__(self):
            super().__init__()
            self.returns = []

        def _on_step(self):
            for info in self.locals.get("infos", []):
                if "episode" in info:
                    self.returns.append(float(info["episode"]["r"]))
            if self.num_timesteps % 2048 == 0 and self.returns:
                rows.append((self.num_timesteps, time.perf_counter() - start, float(np.mean(self.returns))))
                print(f"{rows[-1][0]} steps, {rows[-1][1]:.0f} s, mean return {rows[-1][2]:.2f}", flush=True)
                self.returns = []
            return True

    model = PPO("MlpPolicy", env, seed=args.seed, verbose=0)
    model.learn(total_timesteps=args.timesteps, callback=Curve())
    with open(os.path.join(args.out, "curve.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["env_steps", "wall_s", "mean_return"])
        w.writerows(rows)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot([r[0] for r in rows], [r[2] for r in rows])
    ax.set_xlabel("environment steps (actions)")
    ax.set_ylabel("mean episode return (cm toward the goal)")
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "curve.png"))
    learned = evaluate(lambda o: model.predict(o, deterministic=True)[0], args.eval_episodes, 10_000, env_kwargs)
    space = GoalRollEnv(**env_kwargs).action_space
    space.seed(1)
    random = evaluate(lambda o: space.sample(), args.eval_episodes, 10_000, env_kwargs)
    print(f"learned: reached {learned[0]:.0%}, mean time {learned[1]:.1f} s; "
          f"random: reached {random[0]:.0%}, mean time {random[1]:.1f} s; "
          f"training {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
