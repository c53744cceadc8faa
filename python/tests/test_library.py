"""The library from Python (`import tensegrity`): the same numbers as the command line to the bit,
arrays of the documented shapes, careless calls refused with clear exceptions, and the old names
(`tensegrity_testing`, `tensegrity_native`) still importable with a deprecation warning."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("tensegrity._native")
import tensegrity  # noqa: E402
from tensegrity import NoEquilibrium, PhysicsFailure, SceneError, modes, statics  # noqa: E402
from tensegrity.testing.node import find_executable  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SCENES = ("prism3", "sixbar", "tbar")


def cli_text(*args):
    exe = Path(find_executable()).with_name("tensegrity")
    return subprocess.run([str(exe), *args], capture_output=True, text=True, check=True, cwd=ROOT).stdout


def cli(*args):
    return json.loads(cli_text(*args))


@pytest.mark.parametrize("name", SCENES)
def test_statics_and_modes_are_the_command_lines_to_the_bit(name):
    path = str(ROOT / "config" / "scenes" / f"{name}.toml")
    eq = statics(path)
    assert eq.report == cli("statics", path, "--json"), "every number of statics --json"
    listed = modes(path, count=4)
    assert listed.modes == cli("modes", path, "--json", "--count", "4")
    # the arrays are the report's numbers, float64 in scene order
    assert eq.tensions.dtype == np.float64 and eq.tensions.shape == (len(eq.cable_names),)
    assert [c["tension"] for c in eq.report["cables"]] == eq.tensions.tolist()
    assert eq.point_positions.shape == (len(eq.point_names), 3)
    assert eq.body_orientations.shape == (len(eq.body_names), 4)
    assert listed.frequencies_hz.shape == (len(listed),) and (listed.frequencies_hz >= 0).all()
    # the shapes: mass-normalized over the coordinates, and the points' motion along each
    assert listed.shapes.shape[0] == len(listed) and listed.shapes.shape[1] > 0
    assert listed.point_displacements.shape == (len(listed), len(eq.point_names), 3)
    assert listed.point_names == eq.point_names
    vibrating = ~listed.zero
    assert (np.abs(listed.point_displacements[vibrating]).max(axis=(1, 2)) > 0).all()
    # a bundled name and the file's text give the same equilibrium
    assert np.array_equal(statics(f"bundled:{name}").tensions, eq.tensions)
    assert np.array_equal(statics(text=Path(path).read_text()).tensions, eq.tensions)


def test_prism3_in_a_line():
    eq = statics("bundled:prism3")
    assert eq.stable and eq.stop_reason and eq.tension("ring") > 0
    assert statics().report == eq.report, "no scene: the bundled prism3"
    assert statics(ROOT / "config" / "scenes" / "prism3.toml").report["scene"] == eq.report["scene"]
    first = modes("bundled:prism3", count=1)
    assert abs(first.frequencies_hz[~first.zero][0] - 1.1603) < 1e-3, "docs/cli.md's lowest mode"
    # the bars stand on pins: their lower ends do not move in any mode, their upper ends do
    lower, upper = first.point_names.index("bar0_0.a"), first.point_names.index("bar0_0.b")
    assert np.abs(first.point_displacements[:, lower]).max() < 1e-6
    assert np.linalg.norm(first.point_displacements[~first.zero][0, upper]) > 0.1


def test_careless_calls_raise_clear_exceptions(tmp_path):
    with pytest.raises(SceneError) as e:
        statics(str(tmp_path / "missing.toml"))
    assert e.value.file.endswith("missing.toml") and "cannot read" in e.value.reason
    with pytest.raises(SceneError) as e:
        statics("bundled:prism4")
    assert "prism3" in str(e.value), "lists the bundled scenes"
    bad = (ROOT / "config" / "scenes" / "prism3.toml").read_text().replace("mass = ", "mass = -", 1)
    with pytest.raises(SceneError) as e:
        statics(text=bad)
    assert e.value.line is not None and "mass" in e.value.field, (e.value.line, e.value.field)
    assert isinstance(e.value, ValueError)
    with pytest.raises(ValueError, match="text"):
        statics("bundled:prism3", text=bad)
    for scene in (3, 1.5, ["bundled:prism3"]):
        with pytest.raises(TypeError):
            statics(scene)
    for count in (2.5, -1, True, "3"):
        with pytest.raises(TypeError):
            modes("bundled:prism3", count=count)
    with pytest.raises(KeyError, match="ring"):
        statics().tension("no_such_cable")
    # a robot with nothing under it has no equilibrium to solve for
    floating = (ROOT / "config" / "scenes" / "sixbar.toml").read_text().split("[[grounds]]")[0]
    with pytest.raises(ValueError):
        statics(text=floating)
    assert NoEquilibrium.__mro__[1] is RuntimeError


def test_the_docs_walk_through_runs(capsys, tmp_path, monkeypatch):
    # every ```python block of docs/python.md, in order in one namespace, as a notebook runs them
    pytest.importorskip("matplotlib")
    text = (ROOT / "docs" / "python.md").read_text()
    blocks = [b.split("```", 1)[0] for b in text.split("```python\n")[1:]]
    assert len(blocks) >= 9
    monkeypatch.chdir(tmp_path)
    namespace = {}
    for block in blocks:
        exec(compile(block, "docs/python.md", "exec"), namespace)
    out = capsys.readouterr().out
    for said in ("SceneCheck('prism3'", "Statics('prism3'", "QuasiStaticPath(21 rows", "DynamicRun(2001 rows",
                 "Statics('prism4'", "(3, 3) (3, 4)", "(3, 9, 3)", "no/such/scene.toml", "rate must be finite",
                 "Bag('prism3-run': 501 states", "(501, 4) (501, 3, 3)", "Quasi-static peak tension",
                 "'summary.csv'"):
        assert said in out, (said, out)
    assert (tmp_path / "prism3-deployment.png").stat().st_size > 10_000


@pytest.mark.parametrize("name", ("prism3", "tbar", "tower"))
def test_the_quasi_static_path_is_the_command_lines_csv_byte_for_byte(name):
    from tensegrity import quasi_static

    path = str(ROOT / "config" / "scenes" / f"{name}.toml")
    exe = Path(find_executable()).with_name("tensegrity")
    out = subprocess.run([str(exe), "deploy", path, "--quasi-static", "--steps", "20", "--out", "-"],
                         capture_output=True, text=True, check=True, cwd=ROOT).stdout
    got = quasi_static(path, steps=20)
    assert got.csv == out
    assert len(got) == out.count("\n") - 1 and got["time_s"].dtype == np.float64
    assert set(got["point"]) <= {"load", "arc", "snap"}
    assert got["time_s"][0] == 0.0 and np.all(np.diff(got["time_s"]) >= 0) or "arc" in got["point"]
    with pytest.raises(KeyError, match="time_s"):
        got["no_such_column"]
    for steps in (0, 10**9):
        with pytest.raises(ValueError, match="steps"):
            quasi_static(path, steps=steps)
    with pytest.raises(TypeError):
        quasi_static(path, steps=2.5)


def test_the_field_reference_is_the_command_lines():
    from tensegrity import field_reference

    exe = Path(find_executable()).with_name("tensegrity")
    out = subprocess.run([str(exe), "fields"], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    text = field_reference()
    assert text.strip() == out.strip() and "| `(top level)` | `name` |" in text


def without_wall_time(csv_text):
    """The CSV without its column `wall_us` (each step's wall time, which no two runs share)."""
    rows = [line.split(",") for line in csv_text.splitlines()]
    k = rows[0].index("wall_us")
    return "\n".join(",".join(r[:k] + r[k + 1:]) for r in rows)


@pytest.mark.parametrize("name", ("prism3", "sixbar", "tbar"))
def test_the_dynamic_deployment_is_the_command_lines_csv_byte_for_byte(name, tmp_path):
    path = str(ROOT / "config" / "scenes" / f"{name}.toml")
    out = cli_text("deploy", path, "--dynamic", "--duration", "0.2", "--out", "-")
    run = tensegrity.dynamic(path, duration=0.2)
    assert without_wall_time(run.csv) == without_wall_time(out), "every digit but the wall time's"
    assert (run["wall_us"][1:] > 0).all()
    assert len(run) == 201 and run["time_s"][0] == 0.0 and abs(run["time_s"][-1] - 0.2) < 1e-12
    assert run.summary["steps"] == 200 and run.summary["newton_iterations"] > 0
    # the options are the command line's, with the same effect
    out = cli_text("deploy", path, "--dynamic", "--duration", "0.05", "--dt", "0.002", "--integrator", "ga",
                   "--rho-inf", "0.5", "--from-equilibrium", "--out", "-")
    again = tensegrity.dynamic(path, duration=0.05, dt=0.002, integrator="ga", rho_inf=0.5, from_equilibrium=True)
    assert without_wall_time(again.csv) == without_wall_time(out) and len(again) == 26
    # global error control finds the same local tolerance and makes the same run
    if name == "prism3":
        out = cli_text("deploy", path, "--dynamic", "--duration", "0.1", "--tol", "1e-4", "--global-error",
                       "--out", "-")
        run = tensegrity.dynamic(path, duration=0.1, tol=1e-4, global_error=True)
        assert without_wall_time(run.csv) == without_wall_time(out)
        assert run.summary["global_error"]["requested"] == 1e-4 and run.summary["global_error"]["runs"] >= 2
        with pytest.raises(ValueError, match="tol"):
            tensegrity.dynamic(path, global_error=True)
    # and a bag recorded from Python is one the command line replays bit for bit
    if name == "prism3":
        bag = tmp_path / "bag"
        tensegrity.dynamic(path, duration=0.05, record=bag)
        assert "identical" in cli_text("replay", str(bag))


@pytest.mark.parametrize("kind, options, flags", [
    ("prism", {"n": 4, "cluster": True}, ["--n", "4", "--cluster"]),
    ("tower", {"stages": 2}, ["--stages", "2"]),
    ("atwood", {"m1": 3.0}, ["--m1", "3"]),
    ("sixbar", {"mu": 0.5, "robots": 2}, ["--mu", "0.5", "--robots", "2"]),
])
def test_the_generators_write_the_command_lines_scene(kind, options, flags):
    text = tensegrity.generate(kind, **options)
    assert text == cli_text("generate", kind, *flags)
    assert tensegrity.check(text=text).name


def test_check_counts_as_the_command_line():
    c = tensegrity.check("bundled:sixbar")
    out = cli_text("check", str(ROOT / "config" / "scenes" / "sixbar.toml"))
    assert f"coordinates: {c.coordinates}" in out and f"cables: {c.cables} " in out
    assert c.bodies == 6 and len(c.body_names) == 6 and len(c.cable_names) == c.cables == 24


def test_careless_library_calls_raise_clear_exceptions(tmp_path):
    for call, error, words in [
        (lambda: tensegrity.generate("pyramid"), ValueError, "generators: prism"),
        (lambda: tensegrity.generate("prism", legs=3), ValueError, "its options: n"),
        (lambda: tensegrity.generate("prism", n=3.0), TypeError, "n must be an int"),
        (lambda: tensegrity.generate("prism", n=2), ValueError, "n >= 3"),
        (lambda: tensegrity.generate("sixbar", mu="high"), TypeError, "mu must be a number"),
        (lambda: tensegrity.dynamic("bundled:prism3", dt=float("nan")), ValueError, "dt must be in"),
        (lambda: tensegrity.dynamic("bundled:prism3", integrator="verlet"), ValueError, "rk4"),
        (lambda: tensegrity.dynamic("bundled:prism3", duration=-1), ValueError, "duration must be positive"),
        (lambda: tensegrity.dynamic("bundled:prism3", duration="1"), TypeError, "duration must be a number"),
        (lambda: tensegrity.dynamic(str(tmp_path / "none.toml")), SceneError, "none.toml"),
        (lambda: tensegrity.check(text="[[bodies]]\nname = 3\n"), SceneError, "name"),
        (lambda: tensegrity.dynamic("bundled:prism3", integrator="rk4", dt=0.1), PhysicsFailure, "unstable"),
    ]:
        with pytest.raises(error) as e:
            call()
        assert words in str(e.value), (words, str(e.value))


def test_the_simulator_steps_with_commands_and_survives_careless_ones():
    with tensegrity.Simulator("bundled:prism3") as sim:
        assert sim.actuator_names == ["ring_winch"] and len(sim.cable_names) == 4
        s = sim.step(100, {"ring_winch": -0.01})
        assert s.step == 100 and abs(s.time - 0.1) < 1e-12
        assert s.cable_tension.dtype == np.float64 and s.cable_tension.shape == (4,)
        assert s.body_position.shape == (3, 3) and s.body_orientation.shape == (3, 4)
        assert not s.cable_tension.flags.writeable, "a read-only view of the state, not a copy"
        for commands, error in [
            ({"ring_winch": float("nan")}, tensegrity.CommandRefused),
            ({"ring_winch": {"rate": 1e9}}, tensegrity.CommandRefused),
            ({"no_such_winch": 0.01}, tensegrity.CommandRefused),
            ({"ring_winch": {"speed": 0.01}}, TypeError),
            ({"ring_winch": "fast"}, TypeError),
        ]:
            with pytest.raises(error):
                sim.step(1, commands)
            assert sim.state().step == 100, "a refused command takes no step"
        for steps in (1.5, -1, True):
            with pytest.raises(TypeError):
                sim.step(steps)
        # still usable, and the same commands give the same state to the bit as a fresh one
        s = sim.step(10)
        with tensegrity.Simulator("bundled:prism3") as fresh:
            fresh.step(100, {"ring_winch": -0.01})
            assert np.array_equal(fresh.step(10).cable_tension, s.cable_tension)
        assert sim.reset().step == 0
    with pytest.raises(RuntimeError, match="closed"):
        sim.step(1)
    with pytest.raises(SceneError):
        tensegrity.Simulator("no/such/scene.toml")


def test_the_old_names_still_import_with_a_deprecation_warning():
    code = (
        "import warnings\n"
        "warnings.simplefilter('always')\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    import tensegrity_testing.envs, tensegrity_native\n"
        "    from tensegrity_testing import TensegrityNode, command\n"
        "    from tensegrity_testing.library import statics\n"
        "import tensegrity, tensegrity.envs, tensegrity.testing\n"
        "assert tensegrity_testing.envs is tensegrity.envs and tensegrity_native is tensegrity._native\n"
        "assert TensegrityNode is tensegrity.testing.TensegrityNode and statics is tensegrity.statics\n"
        "print(sorted({str(w.category.__name__) for w in caught}), len(caught))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['DeprecationWarning'] 2", out


def without_columns(table, names):
    """A `Table`'s rows as lists, without the named (timing) columns."""
    keep = [k for k, c in enumerate(table.columns) if c not in names]
    return [[table.columns[k] for k in keep]] + [[row[k] for k in keep] for row in
                                                 (line.split(",") for line in table.csv.splitlines()[1:])]


def markdown_without_last_column(md):
    return [line.rsplit("|", 2)[0] if line.startswith("|") else line for line in md.splitlines()]


def test_study_writes_the_command_lines_tables(tmp_path):
    path = str(ROOT / "config" / "scenes" / "prism3.toml")
    printed = cli_text("study", path, "--ramp-times", "1,2", "--settle", "0.2", "--out", str(tmp_path / "cli"))
    got = tensegrity.study(path, tmp_path / "py", ramp_times=[1, 2], settle=0.2)
    # the summary and every CSV, but for the wall times
    printed = printed.strip().rsplit("\nwritten to ", 1)[0]
    assert markdown_without_last_column(got.markdown.strip()) == markdown_without_last_column(printed)
    assert set(got.tables) == {"quasi_static.csv", "summary.csv", "dynamic_T1.csv", "dynamic_T2.csv"}
    for name, table in got.tables.items():
        cli_table = tensegrity.Table((tmp_path / "cli" / name).read_text())
        walls = {"wall_us", "wall_time_s"}
        assert without_columns(table, walls) == without_columns(cli_table, walls), name
    assert (tmp_path / "py" / "deviation.png").exists()
    friction = tensegrity.study("bundled:tbar", tmp_path / "friction", friction=[0.0, 0.1])
    assert "friction" in friction.markdown.lower() and "friction_path.csv" in friction.tables
    for call, error in [
        (lambda: tensegrity.study(path), TypeError),
        (lambda: tensegrity.study(path, tmp_path / "x", ramp_times=[1], friction=[0.1]), ValueError),
        (lambda: tensegrity.study(path, tmp_path / "x", ramp_times="fast"), TypeError),
        (lambda: tensegrity.study(path, tmp_path / "x", friction=[-1.0]), ValueError),
        (lambda: tensegrity.study(path, tmp_path / "x", point="no_such_point"), ValueError),
    ]:
        with pytest.raises(error):
            call()


def test_work_precision_makes_the_command_lines_runs(tmp_path):
    path = str(ROOT / "config" / "scenes" / "prism3.toml")
    options = ["--reference-dt", "1e-4", "--duration", "0.04", "--sample", "0.02", "--repeats", "1",
               "--tolerances", "1e-3"]
    cli_text("bench", "work-precision", path, *options, "--out", str(tmp_path / "cli"))
    got = tensegrity.work_precision(path, tmp_path / "py", reference_dt=1e-4, duration=0.04, sample=0.02, repeats=1,
                                    tolerances=[1e-3])
    table = got.tables["work_precision.csv"]
    cli_table = tensegrity.Table((tmp_path / "cli" / "work_precision.csv").read_text())
    assert len(table) >= 30, "every integrator's runs"
    assert without_columns(table, {"median_wall_time_s"}) == without_columns(cli_table, {"median_wall_time_s"})
    for kwargs, error in [({"repeats": 0}, ValueError), ({"tolerances": [-1.0]}, ValueError),
                          ({"reference_integrator": "rk4"}, ValueError), ({"repeats": 1.5}, TypeError)]:
        with pytest.raises(error):
            tensegrity.work_precision(path, tmp_path / "bad", **kwargs)


def test_a_bag_reads_as_arrays_and_replays(tmp_path):
    bag_dir = tmp_path / "run"
    run = tensegrity.dynamic("bundled:sixbar", duration=0.1, record=bag_dir)
    assert str(run.summary["bag"]) == str(bag_dir)
    bag = tensegrity.read_bag(bag_dir)
    assert bag.body_position.shape == (101, 6, 3) and bag.body_orientation.shape == (101, 6, 4)
    assert bag.cable_tension.shape == (101, 24) and bag.cable_slack.dtype == bool
    assert bag.cable_names == [c[: -len("_tension_N")] for c in run.columns if c.endswith("_tension_N")]
    assert len(bag.body_names) == 6 and bag.run["scene_name"] == "sixbar"
    # the recorded tensions are the time history's, to the digits the CSV prints
    k = bag.cable_names.index("c05")
    assert np.allclose(bag.cable_tension[:, k], run["c05_tension_N"], rtol=0, atol=1e-8)
    assert np.allclose(bag.time_s, run["time_s"], rtol=0, atol=1e-12)
    info = cli_text("bag", "info", str(bag_dir))
    assert f"Messages:          {bag.info['messages']}" in info
    report = bag.replay()
    assert report["identical"] and report["difference"] is None and report["steps"] == 100
    # another scene's re-run differs, and the first difference is said
    other = tensegrity.replay(bag_dir, scene=ROOT / "config" / "scenes" / "sixbar.toml")
    assert other["identical"]
    for bad in (tmp_path / "missing", tmp_path):
        with pytest.raises(ValueError):
            tensegrity.read_bag(bad)
    # a bag cut short (its writer killed) reads up to the cut, and reindexing repairs it
    assert tensegrity.reindex_bag(bag_dir) is None, "complete: left as it is"
    mcap = next(bag_dir.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) * 2 // 3])
    cut = tensegrity.read_bag(bag_dir)
    assert cut.info["cut_short"] and 0 < len(cut.time_s) < 101
    kept, why = tensegrity.reindex_bag(bag_dir)
    assert kept > 0 and tensegrity.read_bag(bag_dir).info["cut_short"] is None


@pytest.mark.parametrize("call", [
    "tensegrity.dynamic('bundled:prism3', duration=1e5)",       # steps in pieces: stops
    "tensegrity.work_precision('bundled:prism3', tempfile.mkdtemp())",  # minutes of one solve
])
def test_a_long_call_stops_at_ctrl_c(call):
    # KeyboardInterrupt within the 50 ms look for signals, and the library is usable after it
    code = (
        "import signal, tempfile\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "import tensegrity\n"
        "print('ready', flush=True)\n"
        "try:\n"
        f"    {call}\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted', tensegrity.statics().stable, flush=True)\n"
    )
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "ready"
        time.sleep(1.0)
        sent = time.monotonic()
        child.send_signal(signal.SIGINT)
        line = child.stdout.readline().strip()
        assert line == "interrupted True", line
        assert time.monotonic() - sent < 5, "KeyboardInterrupt at once (and the statics after it)"
    finally:
        child.kill()
        child.wait()

def test_the_benchmarks_from_python(tmp_path):
    path = str(ROOT / "config" / "scenes" / "prism3.toml")
    t = tensegrity.step_times(path, steps=50)
    printed = cli_text("bench", "steps", path, "--steps", "50")
    assert f"{t['unknowns']} unknowns" in printed and 0 < t["median_s"] <= t["max_s"]
    assert t["newton_per_step"] >= 1
    got = tensegrity.scaling([1, 2], steps=5, out=tmp_path / "py")
    cli_text("bench", "scaling", "--stages", "1,2", "--steps", "5", "--out", str(tmp_path / "cli"))
    table = got.tables["scaling.csv"]
    cli_table = tensegrity.Table((tmp_path / "cli" / "scaling.csv").read_text())
    timing = {c for c in table.columns if c.endswith("_us") or "wall" in c or "time" in c}
    assert len(table) == len(cli_table) > 0
    assert without_columns(table, timing) == without_columns(cli_table, timing)
    for call in (lambda: tensegrity.step_times(path, steps=0), lambda: tensegrity.scaling([0], out=tmp_path / "x")):
        with pytest.raises((ValueError, TypeError)):
            call()


def test_tables_become_dataframes():
    pd = pytest.importorskip("pandas")
    run = tensegrity.dynamic("bundled:prism3", duration=0.05)
    frame = run.to_pandas()
    assert isinstance(frame, pd.DataFrame) and list(frame.columns) == run.columns and len(frame) == len(run)
    assert np.array_equal(frame["ring_tension_N"].to_numpy(), run["ring_tension_N"])
    path = tensegrity.quasi_static("bundled:prism3", steps=5).to_pandas()
    assert set(path["point"]) <= {"load", "arc", "snap"} and path["time_s"].dtype == np.float64
