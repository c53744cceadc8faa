#!/usr/bin/env python3
"""Per-step cost of our engine beside MuJoCo on the same structures, in one interleaved run.

Not a test and not a test dependency. Set up once (MuJoCo from PyPI in a virtual environment):

    python3 -m venv target/mujoco-venv && target/mujoco-venv/bin/pip install mujoco numpy
    cargo build --release
    taskset -c 0 target/mujoco-venv/bin/python benches/mujoco_compare.py [--rounds 3]

Cases (dt = 1 ms):
  * free 3-strut prism: benches/peers/prism_free_passive.xml (MuJoCo peer model) and
    benches/peers/prism_free.toml (ours: same geometry, masses, EA, damping, rest lengths);
  * 64-stage tower, one clustered cable per stage: benches/peers/tower_maxc_N64.xml (free bodies
    held by soft equality constraints, 1152 DOF) and our generated `tower:per-stage:64` (bars
    joined by exact ball joints, 960 coordinates + 576 joint rows).
MuJoCo is timed as in its peer's bench.py: mj_step(m, d, n) in C from the model's initial state
with a random 1e-3 velocity, median of 3 repeats; ours with `tensegrity bench steps` (median of
5000 steps, a deployment running), generalized-alpha at the default Newton tolerance (1e-9 of the
forces) and at `--newton-tol 1e-6`, and symplectic Euler. Each round times every case once,
alternating engines; the table gives the median over rounds, and the ratios ours / MuJoCo (below
1: ours is faster).

A second table times ours alone on the 256-stage tower (`--tower256-steps 0` skips it), which
has no MuJoCo model here: generalized-alpha at both Newton tolerances.
"""
import argparse
import os
import re
import statistics
import subprocess
import time

import mujoco
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def mujoco_step_us(xml, integrator, dt=1e-3, target=0.25):
    m = mujoco.MjModel.from_xml_path(os.path.join(HERE, "peers", xml))
    m.opt.timestep = dt
    m.opt.integrator = getattr(mujoco.mjtIntegrator, "mjINT_" + integrator.upper())
    d = mujoco.MjData(m)
    d.qvel[:] = np.random.default_rng(0).normal(size=m.nv) * 1e-3
    mujoco.mj_forward(m, d)
    n = 10
    while True:
        t0 = time.perf_counter()
        mujoco.mj_step(m, d, n)
        w = time.perf_counter() - t0
        if w > 0.05 or n >= 10**7:
            break
        n *= 4
    n = max(20, int(n * target / max(w, 1e-9)))
    reps = []
    for _ in range(3):
        t0 = time.perf_counter()
        mujoco.mj_step(m, d, n)
        reps.append((time.perf_counter() - t0) / n)
    assert np.all(np.isfinite(d.qpos))
    return 1e6 * statistics.median(reps)


def ours_step_us(binary, target, integrator, steps, newton_tol=None):
    cmd = [binary, "bench", "steps", target, "--integrator", integrator, "--steps", str(steps)]
    if newton_tol is not None:
        cmd += ["--newton-tol", str(newton_tol)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=ROOT).stdout
    return float(re.search(r"median ([0-9.]+) us/step", out).group(1))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--tensegrity", default=os.path.join(ROOT, "target", "release", "tensegrity"))
    ap.add_argument("--tower256-steps", type=int, default=1500,
                    help="steps per round of ours on tower:per-stage:256 (0: skip)")
    a = ap.parse_args()
    cases = [
        ("free prism", "benches/peers/prism_free.toml", "prism_free_passive.xml", 5000),
        ("64-stage tower, clustered per stage", "tower:per-stage:64", "tower_maxc_N64.xml", 1000),
    ]
    runs = {}
    for r in range(a.rounds):
        for name, ours, xml, steps in cases:
            for key, f in [
                ("ours generalized-alpha", lambda: ours_step_us(a.tensegrity, ours, "generalized-alpha", steps)),
                ("MuJoCo Euler", lambda: mujoco_step_us(xml, "Euler")),
                ("ours generalized-alpha 1e-6",
                 lambda: ours_step_us(a.tensegrity, ours, "generalized-alpha", steps, 1e-6)),
                ("ours symplectic Euler", lambda: ours_step_us(a.tensegrity, ours, "symplectic-euler", steps)),
                ("MuJoCo implicitfast", lambda: mujoco_step_us(xml, "implicitfast")),
            ]:
                runs.setdefault((name, key), []).append(f())
        if a.tower256_steps > 0:
            for key, tol in [("default", None), ("1e-6", 1e-6)]:
                runs.setdefault(("256", key), []).append(
                    ours_step_us(a.tensegrity, "tower:per-stage:256", "generalized-alpha", a.tower256_steps, tol))
        print("round %d done" % (r + 1), flush=True)
    print("\nMuJoCo %s, dt = 1 ms, median over %d interleaved rounds (µs per step)\n" % (mujoco.__version__, a.rounds))
    print("| structure | ours generalized-alpha | ours generalized-alpha, Newton 1e-6 | ours symplectic Euler "
          "| MuJoCo Euler | MuJoCo implicitfast | ours generalized-alpha / implicitfast "
          "| ours Newton 1e-6 / implicitfast | ours symplectic Euler / MuJoCo Euler |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name, *_ in cases:
        med = {k: statistics.median(v) for (n, k), v in runs.items() if n == name}
        ga, ga6, se = med["ours generalized-alpha"], med["ours generalized-alpha 1e-6"], med["ours symplectic Euler"]
        eu, imp = med["MuJoCo Euler"], med["MuJoCo implicitfast"]
        print("| %s | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f |" % (
            name, ga, ga6, se, eu, imp, ga / imp, ga6 / imp, se / eu))
    if a.tower256_steps > 0:
        print("\nours alone, `tower:per-stage:256`, generalized-alpha, %d steps a round, median over %d rounds "
              "(µs per step)\n" % (a.tower256_steps, a.rounds))
        print("| Newton tolerance | µs per step | per round |")
        print("| --- | ---: | --- |")
        for key in ["default", "1e-6"]:
            v = runs[("256", key)]
            print("| %s | %.1f | %s |" % (
                "1e-9 (default)" if key == "default" else key, statistics.median(v),
                ", ".join("%.0f" % x for x in v)))

if __name__ == "__main__":
    main()
