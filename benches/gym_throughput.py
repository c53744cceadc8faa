#!/usr/bin/env python3
"""Steps per second of a learning loop in Python: our Gymnasium environment (`TensegrityEnv`, with
the simulator in process, `backend="inprocess"`, and with a node in lockstep over shared memory,
`backend="node"`) beside MuJoCo's own Python loop (a control write and `mujoco.mj_step`), on the
free 3-strut prism, with one action per physics step and one per 10, quiet actions (a small sine:
the ring stays taut) and random ones (uniform over the action space: the ring goes slack and
taut), MuJoCo with its Euler and its implicitfast integrator, in one interleaved run. Our
plain shared-memory lockstep call (`TensegrityClient.lockstep`, no Gymnasium wrapper) is timed
too, to tell the transport's cost from the wrapper's. Then the vector
environments: `TensegrityVectorEnv` in process (one call steps every simulator, in parallel) and
with nodes (this process steps every node, the nodes in parallel), and Gymnasium's
`AsyncVectorEnv` (a process per environment), with 1, cores and twice as many environments.

Not a test and not a test dependency. Set up once (MuJoCo and Gymnasium from PyPI):

    python3 -m venv target/mujoco-venv
    target/mujoco-venv/bin/pip install mujoco numpy gymnasium cyclonedds iceoryx2==0.10.0 pytest maturin
    target/mujoco-venv/bin/pip install --no-deps ./python
    cargo build --release
    target/mujoco-venv/bin/python benches/gym_throughput.py [--rounds 5] [--actions 2000] \
        [--newton-tol 1e-6] [--no-vector]

Models (dt = 1 ms): benches/peers/prism_free_actuator.xml (MuJoCo, Euler and implicitfast, its vclu0
actuator driven) and benches/peers/prism_free.toml (ours, generalized-alpha, its vclu0 winch
driven by a rate). Each round times every case once, alternating engines; the table gives the
median over rounds of steps per second (physics steps, not actions).
"""
import argparse
import os
import statistics
import time

import mujoco
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
os.environ.setdefault("TENSEGRITY_NODE", os.path.join(ROOT, "target", "release", "tensegrity_node"))

from tensegrity.testing import command  # noqa: E402
from tensegrity.envs import TensegrityEnv, make_vector_env  # noqa: E402


def action_sequence(kind, actions):
    """The actions of a run, drawn before it is timed: `quiet`, a small sine (the ring stays
    taut); `random`, uniform in [-1, 1] (the winch at up to its full rate either way, each action:
    the ring goes slack and taut), seeded."""
    if kind == "quiet":
        return [1e-3 * np.sin(k * 0.01) for k in range(actions)]
    return list(np.random.default_rng(7).uniform(-1.0, 1.0, actions))


def mujoco_steps_per_s(period, actions, integrator, kind):
    m = mujoco.MjModel.from_xml_path(os.path.join(HERE, "peers", "prism_free_actuator.xml"))
    m.opt.timestep = 1e-3
    m.opt.integrator = integrator
    d = mujoco.MjData(m)
    a = m.nu - 1  # a_vclu0
    # its control is the cable's rest-length shift, m: the same sequence scaled to the winch's
    # travel per action at its full rate (1 m/s), as a running sum like ours
    shift = np.cumsum(np.array(action_sequence(kind, actions)) * 1e-3 * period)
    t0 = time.perf_counter()
    for k in range(actions):
        d.ctrl[a] = shift[k]
        mujoco.mj_step(m, d, period)
    return actions * period / (time.perf_counter() - t0)


def ours_steps_per_s(env, period, actions, kind):
    env.action_period = period
    env.reset(seed=0)
    sequence = [np.array([x]) for x in action_sequence(kind, actions)]
    t0 = time.perf_counter()
    for action in sequence:
        env.step(action)
    return actions * period / (time.perf_counter() - t0)


def lockstep_steps_per_s(env, period, actions):
    client = env.node.shm
    client.lockstep(0, reset=True)
    t0 = time.perf_counter()
    for k in range(actions):
        client.lockstep(period, [command(0, rate=1e-4 * np.sin(k * 0.01))])
    return actions * period / (time.perf_counter() - t0)


def vector_steps_per_s(vectorization, backend, n, period, actions):
    scene = os.path.join(HERE, "peers", "prism_free.toml")
    vec = make_vector_env(n, vectorization=vectorization, backend=backend, scene=scene,
                          actuators=["vclu0_winch"], action_period=period, max_episode_steps=10**9)
    try:
        vec.reset(seed=0)
        a = np.zeros((n, 1))
        t0 = time.perf_counter()
        for _ in range(actions):
            vec.step(a)
        return actions * period * n / (time.perf_counter() - t0)
    finally:
        vec.close()


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--actions", type=int, default=2000)
    p.add_argument("--newton-tol", type=float, action="append", default=[],
                   help="also time ours in process at this Newton tolerance (params newton_tolerance)")
    p.add_argument("--no-vector", action="store_true", help="skip the vector environments' table")
    args = p.parse_args()
    scene = os.path.join(HERE, "peers", "prism_free.toml")
    env = TensegrityEnv(scene, actuators=["vclu0_winch"], max_episode_steps=10**9, backend="node")
    native = TensegrityEnv(scene, actuators=["vclu0_winch"], max_episode_steps=10**9, backend="inprocess")
    loose = {tol: TensegrityEnv(scene, actuators=["vclu0_winch"], max_episode_steps=10**9, backend="inprocess",
                                params={"newton_tolerance": tol}) for tol in args.newton_tol}
    cases = {}
    try:
        for _ in range(args.rounds):
            for period in (1, 10):
                for kind in ("quiet", "random"):
                    for name, f in (
                        ("MuJoCo Euler (mj_step, control write)",
                         lambda: mujoco_steps_per_s(period, args.actions, mujoco.mjtIntegrator.mjINT_EULER, kind)),
                        ("MuJoCo implicitfast (mj_step, control write)",
                         lambda: mujoco_steps_per_s(period, args.actions, mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
                                                    kind)),
                        ("ours: TensegrityEnv.step, in process (generalized-alpha)",
                         lambda: ours_steps_per_s(native, period, args.actions, kind)),
                        ("ours: TensegrityEnv.step, node over shared memory",
                         lambda: ours_steps_per_s(env, period, args.actions, kind)),
                    ):
                        cases.setdefault((f"{name}, {kind} actions", period), []).append(f())
                    for tol, e in loose.items():
                        name = f"ours: TensegrityEnv.step, in process, Newton {tol:g}, {kind} actions"
                        cases.setdefault((name, period), []).append(ours_steps_per_s(e, period, args.actions, kind))
                cases.setdefault(("ours: shared-memory lockstep call alone, quiet", period), []).append(
                    lockstep_steps_per_s(env, period, args.actions))
    finally:
        env.close()
        native.close()
        for e in loose.values():
            e.close()
    print(f"free 3-strut prism, dt 1 ms, median of {args.rounds} rounds of {args.actions} actions\n")
    print("| loop | steps/s, one action per step | steps/s, one action per 10 steps |")
    print("| --- | ---: | ---: |")
    for name in dict.fromkeys(n for n, _ in cases):
        row = [statistics.median(cases[(name, p)]) for p in (1, 10)]
        print(f"| {name} | {row[0]:,.0f} | {row[1]:,.0f} |")
    if args.no_vector:
        return
    # vector environments: every environment's steps per second together, an action every 10 steps
    cores = os.cpu_count() or 1
    counts = sorted({1, cores, 2 * cores})
    vectors = {}
    kinds = (
        ("parallel", "inprocess", "TensegrityVectorEnv, in process (every simulator on a core)"),
        ("parallel", "node", "TensegrityVectorEnv, nodes (the nodes in parallel)"),
        ("async", "inprocess", "gymnasium AsyncVectorEnv (a process per env, the simulator in it)"),
    )
    for _ in range(args.rounds):
        for vectorization, backend, _label in kinds:
            for n in counts:
                vectors.setdefault((vectorization, backend, n), []).append(
                    vector_steps_per_s(vectorization, backend, n, 10, args.actions // 4))
    print(f"\nvector environments on {cores} cores, an action every 10 steps, steps/s of all together\n")
    print("| environments | " + " | ".join(str(n) for n in counts) + " |")
    print("| --- | " + " | ".join("---:" for _ in counts) + " |")
    for vectorization, backend, label in kinds:
        row = [statistics.median(vectors[(vectorization, backend, n)]) for n in counts]
        print(f"| {label} | " + " | ".join(f"{x:,.0f}" for x in row) + " |")


if __name__ == "__main__":
    main()
