#!/usr/bin/env python3
"""Work-precision of our integrators beside MuJoCo's on the same deployment, in one run.

Not a test and not a test dependency. Set up once (MuJoCo from PyPI in a virtual environment):

    python3 -m venv target/mujoco-venv && target/mujoco-venv/bin/pip install mujoco numpy
    cargo build --release
    taskset -c 0 target/mujoco-venv/bin/python benches/mujoco_work_precision.py

The scene is the MuJoCo peer's work-precision scene (b): the free 3-strut prism (EA 1e4 N,
c = 10 N s/m) whose clustered vertical cable is shortened 5 % over 0.1 s, 0.3 s simulated.
Ours: benches/peers/prism_free_fast.toml through `tensegrity bench work-precision` (its own
Dormand-Prince reference at 2.5e-6 s). MuJoCo: benches/peers/prism_free_actuator.xml (cables as
tendon actuators, force = -(EA/L0 (L - L0) + c Ldot), tension only), the rest length set at every
force evaluation by a control callback as in the peer's accuracy.py, against its own RK4 reference
at 2.5e-6 s. Both errors are measured the same way: every 4 ms, the largest distance of a bar end
from the reference after the optimal rigid alignment of the sample onto it (Kabsch; the prism
floats free), maximized over the run. MuJoCo's wall time is its engine alone (mj_step over the
same number of steps in C, the rest length frozen, no Python callback), as the peer measured it;
ours is the whole run, actuation and sampling included. Prints both tables and, for 1e-4 m and
1e-6 m, the cheapest run of each engine that meets it.
"""
import argparse
import csv
import os
import statistics
import subprocess
import time

import mujoco
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
EA, SHRINK, T_RAMP, T_END, SAMPLE = 1e4, 0.05, 0.1, 0.3, 4e-3


def kabsch_distance(now, ref):
    """Largest point distance after the optimal rigid alignment of `now` onto `ref`."""
    a, b = now - now.mean(0), ref - ref.mean(0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(u @ vt))
    r = u @ np.diag([1.0, 1.0, d]) @ vt
    return np.linalg.norm(a @ r - b, axis=1).max()


def mujoco_run(integrator, dt, callback=True):
    m = mujoco.MjModel.from_xml_path(os.path.join(HERE, "peers", "prism_free_actuator.xml"))
    m.opt.timestep = dt
    m.opt.integrator = getattr(mujoco.mjtIntegrator, "mjINT_" + integrator.upper())
    d = mujoco.MjData(m)
    for a in range(m.nu):
        d.ctrl[a] = EA / m.actuator_gainprm[a, 0]
    vclu = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, "a_vclu0")
    l0a = d.ctrl[vclu]
    l0b = l0a * (1.0 - SHRINK)

    def control(m_, d_):
        l0 = l0a + (l0b - l0a) * min(1.0, d_.time / T_RAMP)
        k = EA / l0
        m_.actuator_gainprm[vclu, 0] = k
        m_.actuator_biasprm[vclu, 1] = -k
        d_.ctrl[vclu] = l0

    steps = int(round(T_END / dt))
    every = max(1, int(round(SAMPLE / dt)))
    samples = []
    if callback:
        mujoco.set_mjcb_control(control)
    try:
        for i in range(0, steps, every):
            mujoco.mj_step(m, d, min(every, steps - i))
            mujoco.mj_forward(m, d)
            samples.append(d.site_xpos.copy())
    finally:
        mujoco.set_mjcb_control(None)
    return np.array(samples), steps


def mujoco_engine_time(integrator, dt, steps, repeats):
    m = mujoco.MjModel.from_xml_path(os.path.join(HERE, "peers", "prism_free_actuator.xml"))
    m.opt.timestep = dt
    m.opt.integrator = getattr(mujoco.mjtIntegrator, "mjINT_" + integrator.upper())
    walls = []
    for _ in range(repeats):
        d = mujoco.MjData(m)
        for a in range(m.nu):
            d.ctrl[a] = EA / m.actuator_gainprm[a, 0]
        d.qvel[:] = np.random.default_rng(0).normal(size=m.nv) * 1e-3
        t0 = time.perf_counter()
        mujoco.mj_step(m, d, steps)
        walls.append(time.perf_counter() - t0)
    return statistics.median(walls)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tensegrity", default=os.path.join(ROOT, "target", "release", "tensegrity"))
    ap.add_argument("--out", default=os.path.join(ROOT, "target", "wp-free-prism"))
    a = ap.parse_args()

    # ours, through the bench (timed runs one at a time)
    subprocess.run(
        [a.tensegrity, "bench", "work-precision", "benches/peers/prism_free_fast.toml", "--duration", str(T_END),
         "--sample", str(SAMPLE), "--reference-dt", "2.5e-6", "--repeats", str(a.repeats), "--jobs", "1",
         "--out", a.out], check=True, cwd=ROOT, capture_output=True)
    ours = []
    with open(os.path.join(a.out, "work_precision.csv")) as f:
        for r in csv.DictReader(f):
            setting = ("dt %s s" % r["dt_s"]) if r["dt_s"] else ("tol %s m" % r["tolerance_m"])
            ours.append((r["integrator"], setting, float(r["max_point_error_m"]), float(r["median_wall_time_s"])))

    # MuJoCo
    reference, _ = mujoco_run("RK4", 2.5e-6)
    theirs = []
    for integrator in ("Euler", "implicitfast", "RK4"):
        for dt in (4e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4):
            samples, steps = mujoco_run(integrator, dt)
            if not np.all(np.isfinite(samples)):
                continue
            err = max(kabsch_distance(s, r) for s, r in zip(samples, reference))
            theirs.append(("MuJoCo " + integrator, "dt %g s" % dt, err, mujoco_engine_time(integrator, dt, steps, a.repeats)))

    print("MuJoCo %s and ours on the free prism, 5 %% shrink in 0.1 s, 0.3 s simulated; error = largest bar-end "
          "distance from each engine's own reference after rigid alignment, every 4 ms\n" % mujoco.__version__)
    print("| engine / integrator | setting | max point error m | wall time s |")
    print("| --- | --- | ---: | ---: |")
    for name, setting, err, wall in ours + theirs:
        print("| %s | %s | %.3e | %.5f |" % (name, setting, err, wall))
    print()
    for target in (1e-4, 1e-6):
        for label, rows in (("ours", ours), ("MuJoCo", theirs)):
            ok = [r for r in rows if r[2] <= target]
            if ok:
                best = min(ok, key=lambda r: r[3])
                print("%s cheapest at %g m: %s %s, %.3e m in %.5f s  " % (label, target, best[0], best[1], best[2], best[3]))
            else:
                print("%s: no run reached %g m  " % (label, target))


if __name__ == "__main__":
    main()
