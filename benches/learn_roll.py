"""Learning to roll the six-bar robot to a goal with a standard library: SBX's PPO (Stable-Baselines3
on JAX, its default hyperparameters) trains on `tensegrity/SixbarRollGoal-v0` (the bundled six-bar
rover, a goal 1.5 m away in a direction drawn each episode, one cable hauled per action) and
writes the learning curve (`curve.csv` and `curve.png`: environment steps, wall time, mean
return). Then the learned policy, a random one and the hand-written roller of `tests/kit.rs` are
evaluated on the same goals and seeds, held out from training's, on the nominal robot and on
randomized ones (`summary.json`: the success rate and the median time to the goal), and a learned
episode is recorded (`learned.mp4`, and its frames side by side in `learned.png`: the
environment's `rgb_array` frames).

`--workers N` steps the rollouts in N Ray actors, each a process holding an in-process simulator
(`ray_vec_env`), on a local Ray cluster or on the one `--ray-address` names. `--randomize` trains
on robots drawn anew at every reset, observed through noisy pose sensors.

Not a test and not a test dependency: SBX brings Stable-Baselines3 and with it PyTorch from PyPI
(6.2 GB with its CUDA libraries here), and Ray another 0.5 GB. Set up once, from a clone:

    python3 -m venv target/rl-venv
    target/rl-venv/bin/pip install sbx-rl "jax[cpu]" matplotlib "ray[default]" imageio imageio-ffmpeg
    target/rl-venv/bin/pip install './python[gym]'
    target/rl-venv/bin/python benches/learn_roll.py --timesteps 30000 --out target/learn/nominal

docs/learning.md has the commands, the times and the curves.
"""

import argparse
import csv
import json
import os
import sys
import time

import numpy as np

import gymnasium as gym

from tensegrity.envs import SixbarRollGoalEnv

#: The goals and robots every policy is evaluated on: seeds training never draws (training's
#: episodes come from `--seed`'s generator, far below these).
EVALUATION_SEEDS = range(10_000_000, 10_000_000 + 10_000)


def evaluate(policy, episodes, env_kwargs, video=None):
    """Runs `policy(obs, env)` for one episode on each of the first `episodes` evaluation seeds:
    the success rate, the median time to the goal over the successes (s of simulated time), and
    each episode's (reached, time, distance left). `video`: a file for the first episode's frames."""
    env = SixbarRollGoalEnv(render_mode="rgb_array" if video else None, **env_kwargs)
    runs = []
    for i, seed in enumerate(EVALUATION_SEEDS[:episodes]):
        obs, info = env.reset(seed=seed)
        frames = [env.render()] if video and i == 0 else None
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(policy(obs, env))
            done = terminated or truncated
            if frames is not None:
                frames.append(env.render())
        runs.append((bool(info["reached"]), float(info["time"]), float(info["distance"])))
        if frames is not None:
            import imageio.v2 as imageio

            imageio.mimsave(video, frames, fps=env.metadata["render_fps"], macro_block_size=8)
            # and the episode's frames side by side, for a page
            imageio.imwrite(os.path.splitext(video)[0] + ".png", np.concatenate(frames[:7], axis=1))
    env.close()
    times = [t for reached, t, _ in runs if reached]
    return {"success": sum(r for r, _, _ in runs) / len(runs),
            "median_time_s": float(np.median(times)) if times else None, "episodes": runs}


def ray_vec_env(n, env_kwargs, seed):
    """A Stable-Baselines3 `VecEnv` of `n` environments, each in a Ray actor of its own (a process
    holding an in-process simulator, on whichever machine of the cluster Ray places it):
    `step_async` sends every actor its action before `step_wait` waits for any, so the simulators
    step in parallel. An episode that ends is reset in its actor, its last observation in
    `info["terminal_observation"]`, as SB3 expects."""
    import ray
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv

    @ray.remote(num_cpus=1)
    class Worker:
        def __init__(self, kwargs, seed):
            self.env = gym.wrappers.RecordEpisodeStatistics(SixbarRollGoalEnv(**kwargs))
            self.seed = seed

        def reset(self):
            return self.env.reset(seed=self.seed)[0]

        def step(self, action):
            obs, reward, terminated, truncated, info = self.env.step(action)
            info["TimeLimit.truncated"] = truncated and not terminated
            if terminated or truncated:
                info["terminal_observation"] = obs
                obs = self.env.reset()[0]
            return obs, reward, terminated or truncated, info

    class RayVecEnv(VecEnv):
        def __init__(self):
            probe = SixbarRollGoalEnv(**env_kwargs)
            super().__init__(n, probe.observation_space, probe.action_space)
            probe.close()
            self.workers = [Worker.remote(env_kwargs, seed + 1000 * i) for i in range(n)]
            self._pending = None

        def reset(self):
            return np.stack(ray.get([w.reset.remote() for w in self.workers]))

        def step_async(self, actions):
            self._pending = [w.step.remote(int(a)) for w, a in zip(self.workers, actions)]

        def step_wait(self):
            obs, rewards, dones, infos = zip(*ray.get(self._pending))
            return np.stack(obs), np.array(rewards), np.array(dones), list(infos)

        def close(self):
            for w in self.workers:
                ray.kill(w)

        # what SB3's PPO asks a VecEnv for beyond stepping: nothing it needs here
        def get_attr(self, name, indices=None):
            return [None] * self.num_envs

        def set_attr(self, name, value, indices=None):
            pass

        def env_method(self, name, *args, indices=None, **kwargs):
            return [None] * self.num_envs

        def env_is_wrapped(self, wrapper_class, indices=None):
            return [False] * self.num_envs

    return RayVecEnv()


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--timesteps", type=int, default=30_000, help="environment steps (roll actions) to train")
    p.add_argument("--workers", type=int, default=0,
                   help="step the rollouts in this many Ray actors (0: in this process, no Ray)")
    p.add_argument("--ray-address", default=None, help="an existing Ray cluster's address (default: a local one)")
    p.add_argument("--randomize", action="store_true", help="train on randomized robots seen through noisy sensors")
    p.add_argument("--eval-episodes", type=int, default=20, help="episodes per policy and robot (0: none)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="target/learn/nominal")
    args = p.parse_args()
    from sbx import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    train_kwargs = {"randomize": args.randomize}
    start = time.perf_counter()
    if args.workers > 0:
        import ray

        # the actors import the environment from the installed package: every machine of the
        # cluster needs the same wheel installed, nothing else (the rover is built in). Ray
        # reports no usage statistics from here (run it in a loopback-only network namespace)
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        ray.init(address=args.ray_address, include_dashboard=False, log_to_driver=False)
        env = ray_vec_env(args.workers, train_kwargs, args.seed)
    else:
        env = gym.wrappers.RecordEpisodeStatistics(SixbarRollGoalEnv(**train_kwargs))
    rows = []

    class Curve(BaseCallback):
        """The mean return of the episodes that ended in each window of 1024 environment steps."""

        def __init__(self):
            super().__init__()
            self.returns, self.next = [], 1024

        def _on_step(self):
            for info in self.locals.get("infos", []):
                if "episode" in info:
                    self.returns.append(float(info["episode"]["r"]))
            if self.num_timesteps >= self.next and self.returns:
                rows.append((self.num_timesteps, time.perf_counter() - start, float(np.mean(self.returns))))
                print(f"{rows[-1][0]} steps, {rows[-1][1]:.0f} s, mean return {rows[-1][2]:.2f}", flush=True)
                self.returns, self.next = [], self.next + 1024
            return True

    # PPO collects n_steps per environment: 2048 actions per update however many workers
    n_steps = 2048 // max(1, args.workers)
    model = PPO("MlpPolicy", env, n_steps=n_steps, seed=args.seed, verbose=0)
    model.learn(total_timesteps=args.timesteps, callback=Curve())
    trained = time.perf_counter() - start
    env.close()
    with open(os.path.join(out, "curve.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["env_steps", "wall_s", "mean_return"])
        w.writerows(rows)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot([r[0] for r in rows], [r[2] for r in rows])
    ax.set_xlabel("environment steps (roll actions, 1.5 s each)")
    ax.set_ylabel("mean episode return (dm toward the goal)")
    ax.set_title(f"SBX PPO on SixbarRollGoal-v0, {'randomized' if args.randomize else 'nominal'} robot, "
                 + (f"{args.workers} Ray workers" if args.workers else "in process"), fontsize=9)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "curve.png"))
    model.save(os.path.join(out, "policy"))

    rng = np.random.default_rng(1)
    policies = {
        "learned": lambda obs, env: int(model.predict(obs, deterministic=True)[0]),
        "random": lambda obs, env: int(rng.integers(env.action_space.n)),
        "roller (tests/kit.rs)": lambda obs, env: env.roller_action(),
    }
    evaluation = {}
    for robot in ("nominal", "randomized") if args.eval_episodes > 0 else ():
        for name, policy in policies.items():
            video = os.path.join(out, "learned.mp4") if name == "learned" and robot == "nominal" else None
            r = evaluate(policy, args.eval_episodes, {"randomize": robot == "randomized"}, video=video)
            evaluation[f"{name}, {robot}"] = r
            t = "-" if r["median_time_s"] is None else f"{r['median_time_s']:.1f} s"
            print(f"{name:22s} {robot:10s} reached {r['success']:.0%}, median time to the goal {t}", flush=True)
    steps = model.num_timesteps  # whole rollouts: at least --timesteps
    summary = {"timesteps": steps, "workers": args.workers, "randomize": args.randomize, "seed": args.seed,
               "train_wall_s": trained, "env_steps_per_s": steps / trained, "evaluation": evaluation}
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    print(f"training {steps} steps in {trained:.0f} s, {steps / trained:.1f} environment steps/s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
