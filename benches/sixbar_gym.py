#!/usr/bin/env python3
"""`SixbarRoll-v0` from Python beside the six-bar's MuJoCo twin stepped the same way: physics steps
per second of a learning loop that sends random actions (every winch's rest-length target drawn
uniformly between its limits, so cables go slack and taut and the robot tumbles), one action per
50 physics steps of 1 ms, in one interleaved run.

- Ours: `gym.make("tensegrity/SixbarRoll-v0", backend="inprocess")` (`config/scenes/sixbar_rover.toml`,
  generalized-alpha, the simulator in the Python process), `env.step(action)`; an episode that
  ends is reset outside the timed calls.
- Ours again with Newton stopped at 1e-6 of the forces (`params={"newton_tolerance": 1e-6}`, the
  node parameter; the default is 1e-9).
- Ours again with the rover's floor on the regularized friction law (its `stick_stiffness` line
  dropped, `stiction_speed` at its default 1e-5 m/s), for what the stick-slip law gains.
- MuJoCo: the twin `benches/mujoco_sixbar.py` builds, from `sixbar_rover.toml` (its tendons'
  controls are rest lengths), `data.ctrl[:] = action` and `mujoco.mj_step(model, data, nstep=50)`
  (how MuJoCo's own Gymnasium environments skip frames), implicitfast and Euler. Where our winches
  run to their targets at their rate, the twin's rest lengths follow theirs through a first-order
  filter (`dyntype="filterexact"`, time constant `TAU`): a control that jumps (a rest length
  halved at once is a step of kilonewtons) makes the twin unstable within 20 ms, and MuJoCo then
  resets it, so the script counts MuJoCo's instability warnings and reports them.

Not a test and not a test dependency. Set up as for `benches/gym_throughput.py`, then:

    target/mujoco-venv/bin/python benches/sixbar_gym.py [--rounds 5] [--actions 200]
"""
import argparse
import os
import statistics
import sys
import tempfile
import time
import tomllib

import gymnasium as gym
import mujoco
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

from mujoco_sixbar import twin_xml  # noqa: E402
import tensegrity.envs  # noqa: E402,F401  (registers the environments)

PERIOD = 50
TAU = 0.25  # s: the twin's rest lengths reach a new target in about a second, as our winches do
ROVER = os.path.join(ROOT, "config", "scenes", "sixbar_rover.toml")


def random_actions(space, actions, seed=11):
    """`actions` rest-length targets drawn uniformly between the winches' limits, seeded."""
    rng = np.random.default_rng(seed)
    return [rng.uniform(space.low, space.high) for _ in range(actions)]


def ours_steps_per_s(env, actions):
    """Physics steps per second of `env.step` over `actions`, resets not timed."""
    env.reset(seed=3)
    spent = 0.0
    for a in actions:
        t0 = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(a)
        spent += time.perf_counter() - t0
        if terminated or truncated:
            env.reset()
    return PERIOD * len(actions) / spent


def mujoco_steps_per_s(model, actions, rest):
    """Physics steps per second of the twin (the control written, `PERIOD` steps in one call),
    and how many times MuJoCo warned that it went unstable. The filtered rest lengths start at the
    scene's, `rest`."""
    d = mujoco.MjData(model)
    d.act[:] = rest
    d.ctrl[:] = rest
    mujoco.mj_forward(model, d)
    t0 = time.perf_counter()
    for a in actions:
        d.ctrl[:] = a
        mujoco.mj_step(model, d, nstep=PERIOD)
    rate = PERIOD * len(actions) / (time.perf_counter() - t0)
    return rate, d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--actions", type=int, default=200)
    args = parser.parse_args()
    env = gym.make("tensegrity/SixbarRoll-v0", backend="inprocess")
    actions = random_actions(env.action_space, args.actions)
    with open(ROVER, "rb") as f:
        text = f.read().decode()
    scene = tomllib.loads(text)
    regularized_path = os.path.join(tempfile.mkdtemp(), "sixbar_rover_regularized.toml")
    with open(regularized_path, "w") as f:
        f.write("".join(line for line in text.splitlines(True) if not line.startswith("stick_stiffness")))
    regularized = gym.make("tensegrity/SixbarRoll-v0", backend="inprocess", scene=regularized_path)
    loose = gym.make("tensegrity/SixbarRoll-v0", backend="inprocess", params={"newton_tolerance": 1e-6})
    names = [c["name"] for c in scene["cables"]]
    winches = [a["cable"] for a in scene["actuators"]]
    assert winches == names, "the rover has a winch on every cable, in cable order"
    twins = {}
    for label, integrator in (("implicitfast", mujoco.mjtIntegrator.mjINT_IMPLICITFAST),
                              ("Euler", mujoco.mjtIntegrator.mjINT_EULER)):
        xml = twin_xml(scene).replace('gaintype="fixed"', f'dyntype="filterexact" dynprm="{TAU}" gaintype="fixed"')
        m = mujoco.MjModel.from_xml_string(xml)
        m.opt.integrator = integrator
        twins[label] = m
    rest = np.array([c["rest_length"] for c in scene["cables"]])
    rates = {"ours": [], "loose": [], "regularized": [], **{k: [] for k in twins}}
    unstable = {k: 0 for k in twins}
    for _ in range(args.rounds):
        rates["ours"].append(ours_steps_per_s(env, actions))
        rates["loose"].append(ours_steps_per_s(loose, actions))
        rates["regularized"].append(ours_steps_per_s(regularized, actions))
        for label, m in twins.items():
            rate, warnings = mujoco_steps_per_s(m, actions, rest)
            rates[label].append(rate)
            unstable[label] += warnings
    med = {k: statistics.median(v) for k, v in rates.items()}
    print(f"SixbarRoll-v0, random rest-length actions every {PERIOD} steps of 1 ms, "
          f"{args.actions} actions, median of {args.rounds} interleaved rounds (physics steps/s)\n")
    print("| loop | steps/s | ours / this |")
    print("| --- | ---: | ---: |")
    print(f"| ours, `env.step`, in process (generalized-alpha), stick-slip floor (bundled) | {med['ours']:,.0f} | 1.00 |")
    print(f"| ours, the same, Newton tolerance 1e-6 | {med['loose']:,.0f} | {med['ours'] / med['loose']:.2f} |")
    print(f"| ours, the same, regularized floor | {med['regularized']:,.0f} | "
          f"{med['ours'] / med['regularized']:.2f} |")
    for label in twins:
        print(f"| MuJoCo twin, `mj_step(nstep={PERIOD})`, {label}, rest lengths filtered (tau {TAU} s) | "
              f"{med[label]:,.0f} | {med['ours'] / med[label]:.2f} |")
    for label, n in unstable.items():
        print(f"\nMuJoCo {label}: {n} instability warnings over the rounds" + (" (it reset itself: its rate is not a simulation's)" if n else ""))


if __name__ == "__main__":
    main()
