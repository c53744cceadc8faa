#!/usr/bin/env python3
"""The six-bar robot on the ground, ours beside its MuJoCo twin: the twin is built here from
`config/scenes/sixbar.toml`, the sanity check runs both through the roll (both must stand on the
same three strut ends at the start and roll onto the same next face), then per-step cost in one
interleaved run, rolling (the scene's haul of c05, the first 4 s) and resting (4 s, the winch
held), generalized-alpha (ours, at the default Newton tolerance 1e-9 and at `--newton-tol 1e-6`)
against MuJoCo's implicitfast and Euler.

Not a test and not a test dependency. Set up once (MuJoCo from PyPI):

    python3 -m venv target/mujoco-venv
    target/mujoco-venv/bin/pip install mujoco numpy
    cargo build --release
    target/mujoco-venv/bin/python benches/mujoco_sixbar.py [--rounds 5] [--xml out.xml]

The twin: six free bodies with the struts' mass and transverse inertia m L^2/12 (axial m r^2/2:
our bars have no spin about their axis, MuJoCo's bodies do), spheres of the contact radius at
both ends (colliding with the floor only, as ours), 24 spatial tendons between the same ends,
each driven by an actuator whose force is k (ctrl - length) - c v clipped to pulling (k = EA/L0,
c the damping coefficient the scene's damping ratio gives, `2 zeta sqrt(k m_a m_b / (m_a +
m_b))`), the control the cable's rest length over time, as our schedule; a plane with mu 0.8,
condim 3, MuJoCo's default contact solver. Timing: ours `tensegrity bench steps` (its mean and
median us per step, after 10 untimed steps); MuJoCo `mujoco.rollout` (the whole run in C, mean per
step) and, apart, its mean solver iterations per step from a Python loop.
"""
import argparse
import math
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib

import mujoco
import mujoco.rollout
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SCENE = os.path.join(ROOT, "config", "scenes", "sixbar.toml")
BIN = os.path.join(ROOT, "target", "release", "tensegrity")
DT = 1e-3


def scene():
    with open(SCENE, "rb") as f:
        return tomllib.load(f)


def rest_lengths(s, t):
    """Every cable's rest length at schedule time `t`, s (the ramps of `[deployment]`, linear)."""
    rest = [c["rest_length"] for c in s["cables"]]
    names = [c["name"] for c in s["cables"]]
    actuators = {a["name"]: a["cable"] for a in s.get("actuators", [])}
    for ramp in s.get("deployment", {}).get("ramps", []):
        c = names.index(actuators[ramp["actuator"]])
        start, duration, target = ramp["start"], ramp["duration"], ramp["rest_length"]
        f = min(max((t - start) / duration, 0.0), 1.0)
        rest[c] = rest[c] + f * (target - rest[c])
    return rest


def twin_xml(s):
    """The MJCF of the twin of scene `s` (module docs)."""
    bodies = {b["name"]: b for b in s["bodies"]}
    g = s["gravity"]
    mu = s["grounds"][0].get("mu", 0.8)
    out = [
        f'<mujoco model="sixbar_twin"><option timestep="{DT}" gravity="{g[0]} {g[1]} {g[2]}"/>',
        "<worldbody>",
        f'<geom name="floor" type="plane" size="0 0 1" contype="0" conaffinity="1" friction="{mu} 0.005 0.0001"/>',
    ]
    for name, b in bodies.items():
        a, e = np.array(b["ends"][0]), np.array(b["ends"][1])
        length = np.linalg.norm(e - a)
        z = (e - a) / length
        # a quaternion taking the body's z onto the bar, a to b
        axis = np.cross([0, 0, 1], z)
        s_ = np.linalg.norm(axis)
        angle = math.atan2(s_, z[2])
        q = [1, 0, 0, 0] if s_ < 1e-12 else [math.cos(angle / 2), *(math.sin(angle / 2) * axis / s_)]
        m, r = b["mass"], b["contact_radius"]
        it, ia = m * length**2 / 12, m * r**2 / 2
        c = (a + e) / 2
        out.append(f'<body name="{name}" pos="{c[0]} {c[1]} {c[2]}" quat="{q[0]} {q[1]} {q[2]} {q[3]}">')
        out.append("<freejoint/>")
        out.append(f'<inertial pos="0 0 0" mass="{m}" diaginertia="{it} {it} {ia}"/>')
        for end, zz in (("a", -length / 2), ("b", length / 2)):
            out.append(f'<site name="{name}.{end}" pos="0 0 {zz}"/>')
            out.append(
                f'<geom type="sphere" size="{r}" pos="0 0 {zz}" contype="1" conaffinity="0" mass="0" '
                f'condim="3" friction="{mu} 0.005 0.0001"/>'
            )
        out.append("</body>")
    out.append("</worldbody><tendon>")
    for cable in s["cables"]:
        p, q2 = cable["route"]
        out.append(f'<spatial name="{cable["name"]}"><site site="{p}"/><site site="{q2}"/></spatial>')
    out.append("</tendon><actuator>")
    for cable in s["cables"]:
        k = cable["ea"] / cable["rest_length"]
        ma, mb = (bodies[p.split(".")[0]]["mass"] for p in cable["route"])
        damping = 2 * cable.get("damping_ratio", 0.0) * math.sqrt(k * ma * mb / (ma + mb))
        out.append(
            f'<general name="a_{cable["name"]}" tendon="{cable["name"]}" gaintype="fixed" gainprm="{k}" '
            f'biastype="affine" biasprm="0 {-k} {-damping}" ctrllimited="false" forcelimited="true" '
            f'forcerange="-1e12 0"/>'
        )
    out.append("</actuator></mujoco>")
    return "\n".join(out)


def controls(s, steps, rolling):
    """The actuators' controls (rest lengths) of `steps` steps: the schedule, or held at the start."""
    if rolling:
        return np.array([rest_lengths(s, (k + 1) * DT) for k in range(steps)])
    return np.tile(rest_lengths(s, 0.0), (steps, 1))


def ends_on_ground(z, names, below=0.03):
    """The strut ends lower than `below` m, sorted."""
    return sorted(n for n, h in zip(names, z) if h < below)


def mujoco_run(model, s, steps, rolling):
    """Steps the twin in Python: its end heights at the start and after `steps` steps, and its mean
    solver iterations per step."""
    d = mujoco.MjData(model)
    mujoco.mj_forward(model, d)
    ctrl = controls(s, steps, rolling)
    sites = [model.site(i).name for i in range(model.nsite)]
    start = ends_on_ground(d.site_xpos[:, 2], sites)
    iterations = 0
    for k in range(steps):
        d.ctrl[:] = ctrl[k]
        mujoco.mj_step(model, d)
        iterations += d.solver_niter[0]
    return start, ends_on_ground(d.site_xpos[:, 2], sites), iterations / steps


def mujoco_us_per_step(model, s, steps, rolling):
    """Mean wall time of a step of the twin, us, the whole run in C (`mujoco.rollout`)."""
    d = mujoco.MjData(model)
    state = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(model, d, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    ctrl = controls(s, steps, rolling)
    t0 = time.perf_counter()
    mujoco.rollout.rollout(model, d, state, ctrl)
    return 1e6 * (time.perf_counter() - t0) / steps


# our Newton tolerances: the default, and the looser one a user may choose (`--newton-tol`)
NEWTON = (("ours", []), ("ours newton 1e-6", ["--newton-tol", "1e-6"]))


def ours_run(path, steps, extra=()):
    """Our end heights at the start and after `steps` steps of `path` (deploy --dynamic)."""
    with tempfile.TemporaryDirectory() as tmp:
        csv = os.path.join(tmp, "run.csv")
        subprocess.run([BIN, "deploy", "--dynamic", path, "--duration", str(steps * DT), "--out", csv, *extra],
                       check=True, capture_output=True)
        with open(csv) as f:
            header = f.readline().strip().split(",")
            rows = f.read().strip().split("\n")
    cols = [(i, h[: -len("_z_m")]) for i, h in enumerate(header) if re.fullmatch(r"\w+\.[ab]_z_m", h)]
    first, last = (r.split(",") for r in (rows[0], rows[-1]))
    z = lambda row: ends_on_ground([float(row[i]) for i, _ in cols], [n for _, n in cols])  # noqa: E731
    return z(first), z(last)


def ours_us_per_step(path, steps, extra=()):
    """Our mean and median wall time of a step, us, and Newton iterations per step."""
    out = subprocess.run([BIN, "bench", "steps", path, "--steps", str(steps), *extra], check=True,
                         capture_output=True, text=True).stdout
    median = float(re.search(r"median ([0-9.]+) us/step", out).group(1))
    mean = float(re.search(r"mean ([0-9.]+)", out).group(1))
    newton = float(re.search(r"Newton ([0-9.]+)/step", out).group(1))
    return mean, median, newton


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--seconds", type=float, default=4.0)
    p.add_argument("--xml", help="also write the twin's MJCF here")
    args = p.parse_args()
    s = scene()
    xml = twin_xml(s)
    if args.xml:
        with open(args.xml, "w") as f:
            f.write(xml)
    model = mujoco.MjModel.from_xml_string(xml)
    steps = int(round(args.seconds / DT))
    # the resting scene: the same robot with its winch held (no ramp)
    with open(SCENE) as f:
        text = f.read()
    resting = os.path.join(tempfile.mkdtemp(), "sixbar_resting.toml")
    with open(resting, "w") as f:
        f.write(text[: text.index("[[deployment.ramps]]")] + text[text.index("[[grounds]]"):])

    # sanity: the same three ends on the ground at the start, the same face after the roll
    twin = mujoco_run(model, s, steps, True)
    print(f"MuJoCo twin: on the ground at the start {twin[0]}, after {args.seconds} s {twin[1]}")
    same = True
    for name, extra in NEWTON:
        ours = ours_run(SCENE, steps, extra)
        print(f"{name}: on the ground at the start {ours[0]}, after {args.seconds} s {ours[1]}")
        same = same and ours[0] == twin[0] and ours[1] == twin[1] and ours[0] != ours[1]
    print("sanity: " + ("both start on the same ends and roll onto the same face" if same else "DIFFERENT"))
    iterations = {"rolling": twin[2], "resting": mujoco_run(model, s, steps, False)[2]}
    if not same:
        sys.exit(1)

    times = {}
    for _ in range(args.rounds):
        for case, path, rolling in (("rolling", SCENE, True), ("resting", resting, False)):
            for name, extra in NEWTON:
                mean, median, newton = ours_us_per_step(path, steps, extra)
                times.setdefault((case, f"{name} mean"), []).append(mean)
                times.setdefault((case, f"{name} median"), []).append(median)
                times.setdefault((case, f"{name} newton"), []).append(newton)
            for name, integrator in (("implicitfast", mujoco.mjtIntegrator.mjINT_IMPLICITFAST),
                                     ("Euler", mujoco.mjtIntegrator.mjINT_EULER)):
                model.opt.integrator = integrator
                times.setdefault((case, name), []).append(mujoco_us_per_step(model, s, steps, rolling))
            model.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    med = lambda k: statistics.median(times[k])  # noqa: E731
    print(f"\nsix-bar, dt 1 ms, {args.seconds} s, median of {args.rounds} interleaved rounds (us per step)\n")
    print("| case | ours generalized-alpha | mean | median | Newton/step | MuJoCo implicitfast | "
          "MuJoCo Euler | MuJoCo solver iterations/step | ours mean / implicitfast |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for case in ("rolling", "resting"):
        for name, extra in NEWTON:
            label = "Newton 1e-9 (default)" if not extra else "Newton 1e-6 (`--newton-tol 1e-6`)"
            print(f"| {case} | {label} | {med((case, f'{name} mean')):.1f} | {med((case, f'{name} median')):.1f} | "
                  f"{med((case, f'{name} newton')):.2f} | {med((case, 'implicitfast')):.1f} | "
                  f"{med((case, 'Euler')):.1f} | {iterations[case]:.2f} | "
                  f"{med((case, f'{name} mean')) / med((case, 'implicitfast')):.2f} |")


if __name__ == "__main__":
    main()
