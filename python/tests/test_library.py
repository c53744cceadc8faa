"""The library from Python (`tensegrity_testing.library`): the same numbers as the command line to
the bit, arrays of the documented shapes, and careless calls refused with clear exceptions."""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("tensegrity_native")
from tensegrity_testing.library import NoEquilibrium, SceneError, modes, statics  # noqa: E402
from tensegrity_testing.node import find_executable  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SCENES = ("prism3", "sixbar", "tbar")


def cli(*args):
    exe = Path(find_executable()).with_name("tensegrity")
    out = subprocess.run([str(exe), *args], capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(out.stdout)


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


def test_the_docs_examples_run(capsys):
    # every ```python block of docs/python.md, as a reader would paste it
    text = (ROOT / "docs" / "python.md").read_text()
    blocks = [b.split("```", 1)[0] for b in text.split("```python\n")[1:]]
    assert len(blocks) >= 2
    for block in blocks:
        exec(compile(block, "docs/python.md", "exec"), {})
    out = capsys.readouterr().out
    assert "Statics('prism3'" in out and "no/such/scene.toml" in out and "QuasiStaticPath(21 rows" in out


@pytest.mark.parametrize("name", ("prism3", "tbar", "tower"))
def test_the_quasi_static_path_is_the_command_lines_csv_byte_for_byte(name):
    from tensegrity_testing.library import quasi_static

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
    from tensegrity_testing.library import field_reference

    exe = Path(find_executable()).with_name("tensegrity")
    out = subprocess.run([str(exe), "fields"], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    text = field_reference()
    assert text.strip() == out.strip() and "| `(top level)` | `name` |" in text
