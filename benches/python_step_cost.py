"""The in-process learning step's cost from Python under two installs of the package, measured in
one interleaved run: each round runs `TensegrityEnv.step` (backend "inprocess", the free prism of
benches/peers/prism_free.toml, its vclu0 winch driven by a rate, an action every physics step of
1 ms) once in each Python, alternately, and the table gives the median physics steps per second
of each and their ratio. For checking that a change of the packaging (the abi3 wheel of one
install against the per-version extension it replaced) costs the learning loop nothing.

Not a test and not a test dependency. Each Python must import `tensegrity.envs` (or the old
`tensegrity_testing.envs` with `tensegrity_native`):

    python3 benches/python_step_cost.py --python A/bin/python --python B/bin/python [--rounds 9]
"""

import argparse
import os
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))

# one timed loop in the child Python: prints steps per second
CHILD = r"""
import os, sys, time, warnings
import numpy as np
warnings.simplefilter("ignore")
try:
    from tensegrity.envs import TensegrityEnv
except ImportError:
    from tensegrity_testing.envs import TensegrityEnv
scene, kind, actions = sys.argv[1], sys.argv[2], int(sys.argv[3])
env = TensegrityEnv(scene, actuators=["vclu0_winch"], max_episode_steps=10**9, backend="inprocess")
env.action_period = 1
env.reset(seed=0)
if kind == "quiet":
    sequence = [np.array([1e-3 * np.sin(k * 0.01)]) for k in range(actions)]
else:
    sequence = [np.array([x]) for x in np.random.default_rng(7).uniform(-1.0, 1.0, actions)]
for action in sequence[:200]:
    env.step(action)  # warm up
env.reset(seed=0)
t0 = time.perf_counter()
for action in sequence:
    env.step(action)
print(actions / (time.perf_counter() - t0))
"""


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--python", action="append", required=True, help="a Python with the package (twice)")
    p.add_argument("--rounds", type=int, default=9)
    p.add_argument("--actions", type=int, default=5000)
    args = p.parse_args()
    if len(args.python) != 2:
        p.error("give --python twice")
    scene = os.path.join(HERE, "peers", "prism_free.toml")
    rates = {(py, kind): [] for py in args.python for kind in ("quiet", "random")}
    for _ in range(args.rounds):
        for kind in ("quiet", "random"):
            for py in args.python:
                out = subprocess.run([py, "-c", CHILD, scene, kind, str(args.actions)], capture_output=True, text=True,
                                     check=True)
                rates[(py, kind)].append(float(out.stdout.strip()))
    a, b = args.python
    print(f"median of {args.rounds} interleaved rounds of {args.actions} actions, an action every physics step\n")
    print("| actions | steps/s, A | steps/s, B | B / A |")
    print("| --- | ---: | ---: | ---: |")
    for kind in ("quiet", "random"):
        ma, mb = statistics.median(rates[(a, kind)]), statistics.median(rates[(b, kind)])
        print(f"| {kind} | {ma:,.0f} | {mb:,.0f} | {mb / ma:.3f} |")
    print(f"\nA: {a}\nB: {b}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
