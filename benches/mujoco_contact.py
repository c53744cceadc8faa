#!/usr/bin/env python3
"""Ground contact beside MuJoCo: the same three cases in both engines, against their closed forms.

Not a test and not a test dependency. Set up once (MuJoCo from PyPI in a virtual environment):

    python3 -m venv target/mujoco-venv && target/mujoco-venv/bin/pip install mujoco numpy
    cargo build --release
    target/mujoco-venv/bin/python benches/mujoco_contact.py

Cases (g = 9.81 m/s^2, dt = 1 ms, both engines with their implicit integrators: our
generalized-alpha, MuJoCo's implicitfast; MuJoCo's contact at its defaults, solref 0.02 1,
pyramidal cone; ours at k = 1e6 N/m, dissipation 1 s/m, stiction speed 1e-5 m/s):
  * slide: a 1 kg block on a 30 degree incline, mu 0.3: a = g (sin 30 - mu cos 30) = 2.356287
    m/s^2 (ours: a point mass; MuJoCo: a 0.1 m box, which cannot roll);
  * stick: the same at mu 0.6 > tan 30: it must stay put; the drift along the slope over 2 s
    (again with MuJoCo's elliptic cone and impratio 10, its advice against slip);
  * roll: a solid cylinder (radius 0.1 m, length 0.4 m, 1 kg) across the fall line of 30 degrees,
    mu 0.5: rolls without slipping at a = g sin 30 / 1.5 = 3.27 m/s^2 (ours: a rigid body on
    spheres of its radius at its end faces; MuJoCo: a cylinder geom).
Accelerations are fitted (least squares, s = s0 + v0 t + a t^2 / 2) to the position along the
fall line sampled every step over 0.5-1.0 s (the motion has settled onto the slope by then).
"""
import csv
import os
import subprocess
import tempfile

import mujoco
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
G = 9.81
TILT = np.radians(30.0)
NORMAL = np.array([0.0, -np.sin(TILT), np.cos(TILT)])
DOWNHILL = np.array([0.0, -np.cos(TILT), -np.sin(TILT)])


def fitted_acceleration(t, x):
    keep = (t >= 0.5) & (t <= 1.0)
    t, s = t[keep], x[keep] @ DOWNHILL
    a = np.vstack([np.ones_like(t), t, 0.5 * t * t]).T
    return np.linalg.lstsq(a, s, rcond=None)[0][2]


def mujoco_run(body, mu, seconds, option=""):
    xml = f"""
<mujoco>
  <option timestep="0.001" integrator="implicitfast" gravity="0 0 -9.81" {option}/>
  <worldbody>
    <geom type="plane" size="20 20 0.1" euler="30 0 0" friction="{mu} 0.005 0.0001"/>
    {body}
  </worldbody>
</mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    times, positions = [0.0], [d.qpos[:3].copy()]
    while d.time < seconds - 1e-9:
        mujoco.mj_step(m, d)
        times.append(d.time)
        positions.append(d.qpos[:3].copy())
    return np.array(times), np.array(positions)


def ours_run(scene_text, body, seconds):
    binary = os.path.join(ROOT, "target", "release", "tensegrity")
    with tempfile.TemporaryDirectory() as tmp:
        scene = os.path.join(tmp, "scene.toml")
        out = os.path.join(tmp, "run.csv")
        with open(scene, "w") as f:
            f.write(scene_text)
        run = subprocess.run([binary, "deploy", scene, "--dynamic", "--dt", "0.001", "--duration", str(seconds),
                              "--out", out], capture_output=True, text=True)
        if run.returncode != 0:
            raise SystemExit(f"tensegrity deploy failed: {run.stderr}")
        with open(out) as f:
            rows = list(csv.DictReader(f))
    t = np.array([float(r["time_s"]) for r in rows])
    x = np.array([[float(r[f"{body}_{ax}_m"]) for ax in "xyz"] for r in rows])
    return t, x


def num(x):
    return repr(float(x))


def ground(mu):
    return (f"[[grounds]]\nnormal = [0.0, {num(NORMAL[1])}, {num(NORMAL[2])}]\nmu = {mu}\nstiffness = 1e6\n"
            "dissipation = 1.0\nstiction_speed = 1e-5\n")


def block_case(mu, seconds, option=""):
    depth = G * np.cos(TILT) / 1e6  # started at its normal equilibrium
    centre = -NORMAL * depth
    ours = ("gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"block\"\nkind = \"node\"\nmass = 1.0\n"
            f"position = [{num(centre[0])}, {num(centre[1])}, {num(centre[2])}]\ncontact_radius = 0.0\n" + ground(mu))
    box_centre = NORMAL * 0.05
    mj = (f'<body pos="{box_centre[0]} {box_centre[1]} {box_centre[2]}" euler="30 0 0"><freejoint/>'
          f'<geom type="box" size="0.05 0.05 0.05" mass="1" friction="{mu} 0.005 0.0001"/></body>')
    return ours_run(ours, "block", seconds), mujoco_run(mj, mu, seconds, option)


def roll_case(mu, seconds):
    r, half = 0.1, 0.2
    depth = G * np.cos(TILT) / 2e6
    c = NORMAL * (r - depth)
    axial, transverse = 0.5 * r * r, (3 * r * r + 4 * half * half) / 12
    ours = ("gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"roller\"\nkind = \"rigid\"\nmass = 1.0\n"
            f"position = [{num(c[0])}, {num(c[1])}, {num(c[2])}]\ninertia = [{num(axial)}, {num(transverse)}, {num(transverse)}]\n"
            f"points = {{ left = [{half}, 0.0, 0.0], right = [-{half}, 0.0, 0.0] }}\ncontact_radius = {r}\n"
            "contact_points = [\"left\", \"right\"]\n" + ground(mu))
    c = NORMAL * r
    mj = (f'<body pos="{c[0]} {c[1]} {c[2]}"><freejoint/>'
          f'<geom type="cylinder" size="{r} {half}" euler="0 90 0" mass="1" friction="{mu} 0.005 0.0001"/></body>')
    return ours_run(ours, "roller", seconds), mujoco_run(mj, mu, seconds)


def main():
    rows = []
    (t, x), (tm, xm) = block_case(0.3, 1.0)
    exact = G * (np.sin(TILT) - 0.3 * np.cos(TILT))
    rows.append(("slide: block, 30 deg, mu 0.3", "a m/s^2", exact, fitted_acceleration(t, x),
                 fitted_acceleration(tm, xm)))
    drift = lambda x: abs((x[-1] - x[0]) @ DOWNHILL)
    (t, x), (tm, xm) = block_case(0.6, 2.0)
    rows.append(("stick: block, 30 deg, mu 0.6", "drift along the slope in 2 s, m", 0.0, drift(x), drift(xm)))
    (t, x), (tm, xm) = block_case(0.6, 2.0, 'cone="elliptic" impratio="10"')
    rows.append(("stick, MuJoCo with cone elliptic, impratio 10", "drift along the slope in 2 s, m", 0.0,
                 drift(x), drift(xm)))
    (t, x), (tm, xm) = roll_case(0.5, 1.0)
    exact = G * np.sin(TILT) / 1.5
    rows.append(("roll: cylinder, 30 deg, mu 0.5", "a m/s^2", exact, fitted_acceleration(t, x),
                 fitted_acceleration(tm, xm)))
    print(f"MuJoCo {mujoco.__version__}, dt = 1 ms\n")
    print("| case | quantity | closed form | ours | MuJoCo | ours error | MuJoCo error |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: |")
    for case, what, exact, ours, mj in rows:
        if exact != 0.0:
            err = lambda v: f"{(v - exact) / exact:+.1e}"
        else:
            err = lambda v: f"{v:.1e} m"
        print(f"| {case} | {what} | {exact:.6f} | {ours:.6g} | {mj:.6g} | {err(ours)} | {err(mj)} |")


if __name__ == "__main__":
    main()
