#!/usr/bin/env python3
"""Work-precision of our integrators beside MuJoCo's on the same deployment, in one run.

Not a test and not a test dependency. Set up once (MuJoCo from PyPI in a virtual environment):

    python3 -m venv target/mujoco-venv && target/mujoco-venv/bin/pip install mujoco numpy
    cargo build --release
    taskset -c 0 target/mujoco-venv/bin/python benches/mujoco_work_precision.py
    taskset -c 0 target/mujoco-venv/bin/python benches/mujoco_work_precision.py --scene prism3

--scene free-prism (the default): the scene is the MuJoCo peer's work-precision scene (b): the free 3-strut prism (EA 1e4 N,
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

--scene prism3: our bundled config/scenes/prism3.toml (three bars pinned at their lower ends,
three side cables and the clustered ring through the upper ends, EA 5e4 N, the ring winched from
its prestressed rest length to 4.67065 m over 1 s, 1.5 s simulated) and a MuJoCo model written
from it here (`prism3_mjcf`): each bar a body with a ball joint at its lower end, mass and
transverse inertia m L^2 / 12 as ours (MuJoCo needs an axial inertia: 1e-4 kg m^2, as the peer's
pinned towers; nothing turns a bar about its axis), every cable a spatial tendon through its
route's sites with the actuator law above (the ring a closed loop through three sites), the
rest lengths our form-found ones (read from `tensegrity deploy` at t = 0) and the damping our
`damping_ratio` gives (`c = 2 zeta sqrt(k / sum 1/m)`, k = EA / L0). Errors without alignment
(the bars are pinned), every 10 ms, each against its own reference (ours Dormand-Prince at 1e-5
s, MuJoCo RK4 at 1e-5 s).
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


class FreePrism:
    """The peer's free prism: its own MJCF, the vertical clustered cable shortened 5 % in 0.1 s."""

    title = ("the free prism, 5 % shrink in 0.1 s, 0.3 s simulated; error = largest bar-end distance from "
             "each engine's own reference after rigid alignment, every 4 ms")
    t_end, sample, align = T_END, SAMPLE, True
    ours = ["benches/peers/prism_free_fast.toml", "--duration", str(T_END), "--sample", str(SAMPLE),
            "--reference-dt", "2.5e-6"]
    reference_dt = 2.5e-6
    steps = (4e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4)

    def model(self):
        return mujoco.MjModel.from_xml_path(os.path.join(HERE, "peers", "prism_free_actuator.xml"))

    def start(self, m, d):
        for a in range(m.nu):
            d.ctrl[a] = EA / m.actuator_gainprm[a, 0]
        self.vclu = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, "a_vclu0")
        self.l0a = d.ctrl[self.vclu]

    def rest_length(self, t):
        return self.vclu, self.l0a * (1.0 - SHRINK * min(1.0, t / T_RAMP)), EA


class Prism3:
    """Our bundled prism3 and a MuJoCo model written from it (`prism3_mjcf`)."""

    title = ("prism3 (bars pinned at their lower ends, the clustered ring winched in over 1 s), 1.5 s "
             "simulated; error = largest bar-end distance from each engine's own reference, every 10 ms")
    t_end, sample, align = 1.5, 0.01, False
    ours = ["config/scenes/prism3.toml", "--duration", "1.5", "--sample", "0.01", "--reference-dt", "1e-5"]
    reference_dt = 1e-5
    # our bench's fixed steps (each divides the 10 ms sample)
    steps = (5e-3, 2e-3, 1e-3, 5e-4, 2.5e-4, 1e-4)

    def __init__(self, tensegrity):
        self.xml, self.cables, self.ramp = prism3_mjcf(tensegrity)

    def model(self):
        return mujoco.MjModel.from_xml_string(self.xml)

    def start(self, m, d):
        for name, (l0, ea) in self.cables.items():
            a = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, "a_" + name)
            d.ctrl[a] = l0
        self.winch = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, "a_" + self.ramp["cable"])

    def rest_length(self, t):
        r = self.ramp
        l0, ea = self.cables[r["cable"]]
        s = min(1.0, max(0.0, (t - r["start"]) / r["duration"]))
        return self.winch, l0 + s * (r["rest_length"] - l0), ea


def prism3_mjcf(tensegrity):
    """MJCF of config/scenes/prism3.toml (see the module doc); returns it, each cable's (rest
    length, EA) and the winch's ramp."""
    import tomllib

    with open(os.path.join(ROOT, "config", "scenes", "prism3.toml"), "rb") as f:
        scene = tomllib.load(f)
    # our form-found rest lengths: the first row of a run
    out = subprocess.run([tensegrity, "deploy", "config/scenes/prism3.toml", "--dynamic", "--dt", "0.01",
                          "--duration", "0.01", "--out", "-"], check=True, cwd=ROOT, capture_output=True, text=True)
    rows = list(csv.DictReader(out.stdout.splitlines()))
    bodies = {b["name"]: b for b in scene["bodies"]}
    pinned = {j["a"] for j in scene["joints"] if j["kind"] == "pin"}

    def f(v):
        return " ".join("%.12g" % x for x in v)

    xml = ['<mujoco model="prism3">', '  <compiler angle="radian" autolimits="true"/>',
           '  <option timestep="0.001" integrator="Euler" gravity="%s">' % " ".join(
               "%.10g" % g for g in scene.get("gravity", [0.0, 0.0, 0.0])),
           '    <flag contact="disable"/>', '  </option>',
           '  <default><geom contype="0" conaffinity="0"/></default>', '  <worldbody>']
    for name, b in bodies.items():
        assert b["kind"] == "bar" and name + ".a" in pinned, "prism3's bars are pinned at end a"
        a, e = np.array(b["ends"][0]), np.array(b["ends"][1])
        mid, u = 0.5 * (a + e), e - a
        length = np.linalg.norm(u)
        z = u / length
        # a quaternion turning the body's z axis onto the bar
        w = np.cross([0.0, 0.0, 1.0], z)
        q = np.array([1.0 + z[2], *w])
        q = q / np.linalg.norm(q)
        it = b["mass"] * length ** 2 / 12.0
        xml += ['    <body name="%s" pos="%s">' % (name, f(mid)),
                '      <joint name="%s_pin" type="ball" pos="%s"/>' % (name, f(-u / 2)),
                '      <inertial pos="0 0 0" quat="%s" mass="%.12g" diaginertia="%.12g %.12g 1e-4"/>'
                % (f(q), b["mass"], it, it),
                '      <geom type="capsule" fromto="%s %s" size="0.015"/>' % (f(-u / 2), f(u / 2)),
                '      <site name="%s.a" pos="%s"/>' % (name, f(-u / 2)),
                '      <site name="%s.b" pos="%s"/>' % (name, f(u / 2)),
                '    </body>']
    xml += ['  </worldbody>', '  <tendon>']
    cables, actuators = {}, []
    for c in scene["cables"]:
        l0 = float(rows[0]["%s_rest_length_m" % c["name"]])
        k = c["ea"] / l0
        inv_m = sum(1.0 / bodies[n]["mass"] for n in {p.split(".")[0] for p in c["route"]})
        damping = 2.0 * c["damping_ratio"] * (k / inv_m) ** 0.5
        cables[c["name"]] = (l0, c["ea"])
        xml.append('    <spatial name="%s" width="0.005">' % c["name"])
        xml += ['      <site site="%s"/>' % p for p in c["route"]]
        xml.append('    </spatial>')
        actuators.append('    <general name="a_%s" tendon="%s" gaintype="fixed" gainprm="%.12g" biastype="affine" '
                         'biasprm="0 %.12g %.12g" ctrllimited="false" forcelimited="true" forcerange="-1e12 0"/>'
                         % (c["name"], c["name"], k, -k, -damping))
    xml += ['  </tendon>', '  <actuator>'] + actuators + ['  </actuator>', '</mujoco>']
    (ramp,) = scene["deployment"]["ramps"]
    (winch,) = [a for a in scene["actuators"] if a["name"] == ramp["actuator"]]
    ramp = dict(ramp, cable=winch["cable"])
    return "\n".join(xml), cables, ramp


def prism3_model_check(case, tensegrity):
    """Largest bar-end distance between MuJoCo's RK4 and our Dormand-Prince, both at 0.1 ms, every
    10 ms over prism3's 1.5 s: the two models are the same structure if this is round-off."""
    samples, _ = mujoco_run(case, "RK4", 1e-4)
    out = subprocess.run([tensegrity, "deploy", "config/scenes/prism3.toml", "--dynamic", "--integrator",
                          "dormand-prince", "--dt", "1e-4", "--duration", "1.5", "--out", "-"],
                         check=True, cwd=ROOT, capture_output=True, text=True)
    rows = list(csv.DictReader(out.stdout.splitlines()))
    m = case.model()
    sites = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_SITE, i) for i in range(m.nsite)]
    worst = 0.0
    for k, sample in enumerate(samples):
        row = rows[(k + 1) * 100]
        ours = np.array([[float(row["%s_%s_m" % (n, x)]) for x in "xyz"] for n in sites])
        worst = max(worst, np.linalg.norm(ours - sample, axis=1).max())
    return worst


def mujoco_run(case, integrator, dt, callback=True):
    m = case.model()
    m.opt.timestep = dt
    m.opt.integrator = getattr(mujoco.mjtIntegrator, "mjINT_" + integrator.upper())
    d = mujoco.MjData(m)
    case.start(m, d)

    def control(m_, d_):
        a, l0, ea = case.rest_length(d_.time)
        k = ea / l0
        m_.actuator_gainprm[a, 0] = k
        m_.actuator_biasprm[a, 1] = -k
        d_.ctrl[a] = l0

    steps = int(round(case.t_end / dt))
    every = max(1, int(round(case.sample / dt)))
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


def mujoco_engine_time(case, integrator, dt, steps, repeats):
    m = case.model()
    m.opt.timestep = dt
    m.opt.integrator = getattr(mujoco.mjtIntegrator, "mjINT_" + integrator.upper())
    walls = []
    for _ in range(repeats):
        d = mujoco.MjData(m)
        case.start(m, d)
        d.qvel[:] = np.random.default_rng(0).normal(size=m.nv) * 1e-3
        t0 = time.perf_counter()
        mujoco.mj_step(m, d, steps)
        walls.append(time.perf_counter() - t0)
    return statistics.median(walls)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tensegrity", default=os.path.join(ROOT, "target", "release", "tensegrity"))
    ap.add_argument("--scene", choices=["free-prism", "prism3"], default="free-prism")
    ap.add_argument("--out", help="our bench's output directory (default target/wp-SCENE)")
    a = ap.parse_args()
    case = Prism3(a.tensegrity) if a.scene == "prism3" else FreePrism()
    out = a.out or os.path.join(ROOT, "target", "wp-" + a.scene)

    # ours, through the bench (timed runs one at a time)
    subprocess.run(
        [a.tensegrity, "bench", "work-precision"] + case.ours + ["--repeats", str(a.repeats), "--jobs", "1",
                                                                 "--out", out], check=True, cwd=ROOT,
        capture_output=True)
    ours = []
    with open(os.path.join(out, "work_precision.csv")) as f:
        for r in csv.DictReader(f):
            setting = ("dt %s s" % r["dt_s"]) if r["dt_s"] else ("tol %s m" % r["tolerance_m"])
            ours.append((r["integrator"], setting, float(r["max_point_error_m"]), float(r["median_wall_time_s"])))

    # MuJoCo
    reference, _ = mujoco_run(case, "RK4", case.reference_dt)
    distance = kabsch_distance if case.align else (lambda now, ref: np.linalg.norm(now - ref, axis=1).max())
    theirs = []
    for integrator in ("Euler", "implicitfast", "RK4"):
        for dt in case.steps:
            samples, steps = mujoco_run(case, integrator, dt)
            if not np.all(np.isfinite(samples)):
                continue
            err = max(distance(s, r) for s, r in zip(samples, reference))
            theirs.append(("MuJoCo " + integrator, "dt %g s" % dt, err,
                           mujoco_engine_time(case, integrator, dt, steps, a.repeats)))

    if a.scene == "prism3":
        print("Model check: MuJoCo's RK4 and our dormand-prince, both at dt = 1e-4 s, differ by at most %.1e m "
              "(bar ends every 10 ms over 1.5 s).\n" % prism3_model_check(case, a.tensegrity))
    print("MuJoCo %s and ours on %s\n" % (mujoco.__version__, case.title))
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
