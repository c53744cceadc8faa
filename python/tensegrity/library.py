"""The library's whole commands from Python, arrays out: a scene's counts and names (`check`),
its static equilibrium (`statics`), its natural modes (`modes`), its quasi-static and dynamic
deployments (`quasi_static`, `dynamic`), the deployment and friction studies (`study`), the
integrators' work-precision (`work_precision`), recorded bags (`read_bag`, `replay`), the
generated scenes (`generate`) and the scene-file field reference (`field_reference`), with the
numbers the command line's `check`, `statics --json`, `modes --json`, `deploy`, `study`, `bench
work-precision`, `replay`, `generate` and `fields` write, to the bit (they call the same library
code).

A scene is a file path, `"bundled:NAME"`, None (the bundled prism3), or TOML text given as
`text=`. A scene that cannot be read or is invalid raises `SceneError` (a `ValueError` with
`file`, `line`, `field` and `reason`); a scene with a body nothing holds raises `ValueError`; a
solve that ends without an equilibrium raises `NoEquilibrium` (a `RuntimeError` with
`iterations`, `residual_n`, `stop_reason`). Units are SI: m, N, J, Hz.

    from tensegrity import statics, modes
    eq = statics("bundled:prism3")
    eq.tensions                      # numpy float64, N, in eq.cable_names order
    modes("bundled:prism3", count=3).frequencies_hz
"""

import json
import os

import numpy as np
from . import _native
from ._native import NoEquilibrium, PhysicsFailure, SceneError

__all__ = ["check", "statics", "modes", "quasi_static", "dynamic", "generate", "field_reference", "study",
           "work_precision", "step_times", "scaling", "read_bag", "replay", "reindex_bag", "Bag", "StudyResult", "SceneCheck", "Statics", "Modes", "Table",
           "QuasiStaticPath", "DynamicRun", "SceneError", "NoEquilibrium", "PhysicsFailure"]


def _scene_arg(scene):
    if scene is None:
        return None
    if isinstance(scene, os.PathLike):
        return os.fspath(scene)
    if not isinstance(scene, str):
        raise TypeError(f"scene must be a path, 'bundled:NAME' or None, got {type(scene).__name__}")
    return scene


def _text_arg(text):
    if text is not None and not isinstance(text, str):
        raise TypeError(f"text must be the scene's TOML as a str, got {type(text).__name__}")
    return text


class SceneCheck:
    """A valid scene's counts and names, as `tensegrity check` counts them: `report` (the dict),
    `name`, `bodies` (total), `coordinates`, `constraints`, `cables`, `actuators`, `pulleys`,
    `grounds`, `contact_spheres`, and `body_names`, `cable_names`, `actuator_names`."""

    def __init__(self, report):
        self.report = report
        self.name = report["name"]
        self.bodies = sum(report["bodies"])
        for key in ("coordinates", "constraints", "cables", "actuators", "pulleys", "grounds", "contact_spheres",
                    "body_names", "cable_names", "actuator_names"):
            setattr(self, key, report[key])

    def __repr__(self):
        return (f"SceneCheck({self.name!r}: {self.bodies} bodies, {self.coordinates} coordinates, "
                f"{self.cables} cables, {self.actuators} actuators)")


def check(scene=None, *, text=None):
    """Reads and validates `scene` (a file, `"bundled:NAME"`, None for the bundled prism3) or the
    TOML `text`: a `SceneCheck`, or `SceneError` naming the file, line, field and reason."""
    return SceneCheck(json.loads(_native.check_json(_scene_arg(scene), text=_text_arg(text))))


class Statics:
    """A static equilibrium.

    - `report`: the whole `statics --json` output as a dict;
    - `iterations`, `stop_reason`, `residual_n` (N), `stable`, `potential_energy_j` (J);
    - `cable_names` and, in that order, `tensions` (N; an elastic member's is negative in
      compression), `lengths` and `rest_lengths` (m), `strains`, `slack` (bool): arrays of shape
      `(cables,)`;
    - `point_names` and `point_positions` (m), shape `(points, 3)`;
    - `body_names`, `body_positions` (m, `(bodies, 3)`) and `body_orientations` (unit
      quaternions `[x, y, z, w]`, `(bodies, 4)`);
    - `contacts` and `joints`: the reports' lists of dicts (forces in N).
    """

    def __init__(self, report):
        self.report = report
        self.iterations = report["iterations"]
        self.stop_reason = report["stop_reason"]
        self.residual_n = report["residual_n"]
        self.stable = report["stable"]
        self.potential_energy_j = report["potential_energy_j"]
        cables = report["cables"]
        self.cable_names = [c["name"] for c in cables]
        self.tensions = np.array([c["tension"] for c in cables], dtype=np.float64)
        self.lengths = np.array([c["length"] for c in cables], dtype=np.float64)
        self.rest_lengths = np.array([c["rest_length"] for c in cables], dtype=np.float64)
        self.strains = np.array([c["strain"] for c in cables], dtype=np.float64)
        self.slack = np.array([c["slack"] for c in cables], dtype=bool)
        self.point_names = [p[0] for p in report["points"]]
        self.point_positions = np.array([p[1] for p in report["points"]], dtype=np.float64).reshape(-1, 3)
        self.body_names = [b["name"] for b in report["bodies"]]
        self.body_positions = np.array([b["position"] for b in report["bodies"]], dtype=np.float64).reshape(-1, 3)
        self.body_orientations = np.array([b["orientation"] for b in report["bodies"]],
                                          dtype=np.float64).reshape(-1, 4)
        self.contacts = report.get("contacts", [])
        self.joints = report["joints"]

    def tension(self, cable):
        """The tension of the cable named `cable`, N (`KeyError` naming the cables if none is)."""
        try:
            return float(self.tensions[self.cable_names.index(cable)])
        except ValueError:
            raise KeyError(f"no cable {cable!r} (cables: {', '.join(self.cable_names)})") from None

    def __repr__(self):
        return (f"Statics({self.report['scene']!r}: {self.iterations} Newton iterations, "
                f"{'stable' if self.stable else 'not stable'}, {len(self.cable_names)} cables)")


def statics(scene=None, *, text=None):
    """The equilibrium of `scene` (or of the TOML `text`) at its initial rest lengths: a
    `Statics`. The solve runs without holding the GIL."""
    return Statics(json.loads(_native.statics_json(_scene_arg(scene), text=_text_arg(text))))


class Modes:
    """Natural modes at the equilibrium: `modes` (the `modes --json` list of dicts: every
    zero-frequency mode, then the lowest `count` others), and as arrays in that order `index`
    (1-based among all modes), `frequencies_hz` (Hz; 0 for zero and unstable modes),
    `omega_squared` (1/s^2) and `zero` (bool); the shapes: `shapes` `(modes, coordinates)` (the
    mass-normalized eigenvectors over the generalized coordinates) and `point_displacements`
    `(modes, points, 3)` (each named point's displacement per unit modal amplitude, m), with
    `point_names`."""

    def __init__(self, listed, shapes=None, displacements=None, point_names=()):
        self.modes = listed
        self.index = np.array([m["index"] for m in listed], dtype=np.int64)
        self.frequencies_hz = np.array([m["frequency_hz"] for m in listed], dtype=np.float64)
        self.omega_squared = np.array([m["omega_squared"] for m in listed], dtype=np.float64)
        self.zero = np.array([m["zero_frequency"] for m in listed], dtype=bool)
        n = len(listed)
        self.point_names = list(point_names)
        shapes = np.zeros(0) if shapes is None else shapes
        displacements = np.zeros(0) if displacements is None else displacements
        self.shapes = shapes.reshape(n, -1) if n else shapes.reshape(0, 0)
        self.point_displacements = displacements.reshape(n, len(self.point_names), 3)

    def __len__(self):
        return len(self.modes)

    def __repr__(self):
        return f"Modes({len(self.modes)} listed, lowest vibrating {self.frequencies_hz[~self.zero][:3]} Hz)"


def modes(scene=None, count=10, *, text=None):
    """The natural modes of `scene` (or of the TOML `text`) at its equilibrium: `Modes`, with
    every zero-frequency mode and the lowest `count` vibrating ones."""
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 0:
        raise TypeError(f"count must be a non-negative int, got {count!r}")
    listed, shapes, displacements, point_names = _native.modes_json(_scene_arg(scene), int(count),
                                                                    text=_text_arg(text))
    return Modes(json.loads(listed), shapes, displacements, point_names)


class Table:
    """A command's CSV as arrays: `csv` (the text the command line writes, byte for byte),
    `columns` (its header names) and `data` (column name -> numpy array: float64 for numbers, str
    for text columns). `table["time_s"]` is `table.data["time_s"]`; `len(table)` is its rows;
    `to_pandas()` is a DataFrame (with pandas installed)."""

    def __init__(self, csv_text):
        self.csv = csv_text
        lines = csv_text.splitlines()
        self.columns = lines[0].split(",")
        rows = [line.split(",") for line in lines[1:]]
        self.data = {}
        for k, name in enumerate(self.columns):
            values = [r[k] for r in rows]
            try:
                self.data[name] = np.array([float(v) for v in values], dtype=np.float64)
            except ValueError:
                self.data[name] = np.array(values, dtype=str)

    def __getitem__(self, column):
        try:
            return self.data[column]
        except KeyError:
            raise KeyError(f"no column {column!r} (columns: {', '.join(self.columns)})") from None

    def __len__(self):
        return len(self.csv.splitlines()) - 1

    def to_pandas(self):
        """The table as a pandas DataFrame (pandas must be installed)."""
        import pandas as pd

        return pd.DataFrame({name: self.data[name] for name in self.columns})

    def __repr__(self):
        return f"{type(self).__name__}({len(self)} rows, {len(self.columns)} columns)"


class QuasiStaticPath(Table):
    """The equilibrium path along a scene's deployment schedule, one row per load step (and per
    point traced by arc length past a limit point): the `Table` of `tensegrity deploy
    --quasi-static --out -`. Its `point` column says `load`, `arc` or `snap`."""


def quasi_static(scene=None, steps=None, *, text=None):
    """The quasi-static deployment of `scene` (or of the TOML `text`) along its schedule, in
    `steps` load steps (default the scene's): a `QuasiStaticPath`. A path that ends without an
    equilibrium (a robot tipping over) raises `NoEquilibrium`."""
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, (int, np.integer))):
        raise TypeError(f"steps must be an int, got {steps!r}")
    return QuasiStaticPath(_native.quasi_static_csv(_scene_arg(scene), None if steps is None else int(steps),
                                                   text=_text_arg(text)))


class DynamicRun(Table):
    """A dynamic deployment's time history, one row per step from t = 0: the `Table` of
    `tensegrity deploy --dynamic --out -` (time, energies, each cable's tension, length and rest
    length, each body's pose, ...; the scene's sensors after them), and `summary`: `steps`,
    `newton_iterations`, `rejected`, `substeps`, `wall_time_s`, `struts_collided`, `bag` (the
    bag's directory, with `record`)."""

    def __init__(self, csv_text, summary):
        super().__init__(csv_text)
        self.summary = summary


def _number_or_none(name, x):
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {x!r}")
    return float(x)


def dynamic(scene=None, *, text=None, integrator="generalized-alpha", dt=None, rho_inf=0.8, tol=None,
            newton_tol=None, duration=None, from_equilibrium=False, record=None, global_error=False):
    """The dynamic deployment of `scene` (or of the TOML `text`) along its schedule, as
    `tensegrity deploy --dynamic` runs it with the same options: `integrator`
    ("generalized-alpha" or "ga", "symplectic-euler" or "euler", "rk4", "dormand-prince" or
    "dopri5"), `dt` (s; default the scene's `physics_dt`, else 1 ms), `rho_inf`, `tol` (m, local
    error control), `newton_tol`, `duration` (s; default the schedule's end + 1 s),
    `from_equilibrium` (start at rest in the static equilibrium) and `record` (a new bag
    directory). With `global_error` (and `tol`, then the global tolerance), runs again at a tenth
    of the tolerance until two runs agree (`deploy --global-error`; `summary["global_error"]`
    says what was found). A `DynamicRun`. A step that fails raises `PhysicsFailure`; Ctrl-C
    raises `KeyboardInterrupt` within a few hundred steps."""
    if not isinstance(integrator, str):
        raise TypeError(f"integrator must be a name (str), got {integrator!r}")
    for name, flag in (("from_equilibrium", from_equilibrium), ("global_error", global_error)):
        if not isinstance(flag, bool):
            raise TypeError(f"{name} must be a bool, got {flag!r}")
    csv_text, summary = _native.dynamic_csv(
        _scene_arg(scene), text=_text_arg(text), integrator=integrator, dt=_number_or_none("dt", dt),
        rho_inf=_number_or_none("rho_inf", rho_inf), tol=_number_or_none("tol", tol),
        newton_tol=_number_or_none("newton_tol", newton_tol), duration=_number_or_none("duration", duration),
        from_equilibrium=from_equilibrium, record=None if record is None else os.fspath(record),
        global_error=global_error)
    return DynamicRun(csv_text, summary)


def generate(kind, **options):
    """The scene `tensegrity generate KIND` writes, as TOML text (give it to any function as
    `text=`). Kinds and options (the command line's, `_` for `-`):

    - `"prism"`: `n` (3), `cluster` (False), `prestress` (100 N), `nodal_strut_ea` (N),
      `consistent_mass` (False);
    - `"tower"`: `n` (3), `stages` (3);
    - `"tbar"`: `hinged_hub`, `nodal_strut_ea`, `consistent_mass`;
    - `"atwood"`: `m1` (2 kg), `m2` (1 kg);
    - `"sixbar"`: `mu` (0.8), `all_winches` (False), `robots` (1).

    An unknown kind or option, or a value of the wrong type or out of range, raises `ValueError`
    or `TypeError` naming it."""
    if not isinstance(kind, str):
        raise TypeError(f"kind must be a generator's name (str), got {kind!r}")
    return _native.generate_toml(kind, options)


def field_reference():
    """The scene-file field reference (every table and field: format, unit, default, range) as
    the Markdown table `tensegrity fields` prints."""
    return _native.field_reference()


class StudyResult:
    """What `study` or `work_precision` wrote: `markdown` (the summary table the command line
    prints), `out` (the directory) and `tables` (file name -> `Table`, every CSV written there)."""

    def __init__(self, markdown, out):
        self.markdown = markdown
        self.out = out
        self.tables = {}
        for name in sorted(os.listdir(out)):
            if name.endswith(".csv"):
                with open(os.path.join(out, name)) as f:
                    self.tables[name] = Table(f.read())

    def __repr__(self):
        return f"StudyResult({self.out!r}: {', '.join(self.tables)})"


def _numbers(name, values):
    if values is None:
        return None
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a list of numbers, got {values!r}") from None
    if any(isinstance(v, bool) for v in values):
        raise TypeError(f"{name} must be a list of numbers, got {values!r}")
    return out


def _count(name, x):
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or x < 0:
        raise TypeError(f"{name} must be a non-negative int, got {x!r}")
    return int(x)


def study(scene=None, out=None, *, text=None, ramp_times=None, point=None, friction=None, settle=1.0, jobs=0,
          integrator="generalized-alpha", dt=None, rho_inf=0.8, tol=None, newton_tol=None):
    """`tensegrity study`: the quasi-static path and dynamic deployments at several actuation
    times `ramp_times` (s; default the scene's actuation time times 0.02 ... 5), or with
    `friction` the quasi-static deployment at each pulley-friction coefficient; `point` is the
    tracked point (default the one that moves most), `settle` the time simulated after the
    schedule (s), `jobs` the threads (0: one per core), and the integrator options as in
    `dynamic`. Writes the command line's files into the directory `out` (required) and returns a
    `StudyResult`."""
    if out is None:
        raise TypeError("study needs out=, the directory its CSVs and plots go to")
    md = _native.study_markdown(
        _scene_arg(scene), os.fspath(out), text=_text_arg(text), ramp_times=_numbers("ramp_times", ramp_times),
        point=point, friction=_numbers("friction", friction), settle=_number_or_none("settle", settle),
        jobs=_count("jobs", jobs), integrator=integrator, dt=_number_or_none("dt", dt),
        rho_inf=_number_or_none("rho_inf", rho_inf), tol=_number_or_none("tol", tol),
        newton_tol=_number_or_none("newton_tol", newton_tol))
    return StudyResult(md, os.fspath(out))


def work_precision(scene=None, out=None, *, text=None, reference_dt=1e-5, reference_integrator="dormand-prince",
                   repeats=3, duration=None, sample=0.01, jobs=0, tolerances=None, global_control=False):
    """`tensegrity bench work-precision`: every integrator at its fixed steps and tolerances
    against a converged reference (`reference_integrator` at `reference_dt` s), error (m) against
    wall time; `repeats` timed runs each, over `duration` s (default the schedule's end + 0.5 s),
    sampled every `sample` s; `tolerances` (m) of the error-controlled runs; `global_control` adds
    generalized-alpha under global error control. Writes `work_precision.{csv,md,png,svg}` into
    `out` (required) and returns a `StudyResult` (minutes at the defaults)."""
    if out is None:
        raise TypeError("work_precision needs out=, the directory its table and plot go to")
    md = _native.work_precision_markdown(
        _scene_arg(scene), os.fspath(out), text=_text_arg(text), reference_dt=_number_or_none("reference_dt", reference_dt),
        reference_integrator=reference_integrator, repeats=_count("repeats", repeats),
        duration=_number_or_none("duration", duration), sample=_number_or_none("sample", sample),
        jobs=_count("jobs", jobs), tolerances=_numbers("tolerances", tolerances), global_control=bool(global_control))
    return StudyResult(md, os.fspath(out))


class Bag:
    """A recorded run (a rosbag2 directory or its `.mcap` file, from the node, `deploy --record`
    or `dynamic(record=...)`), read into arrays:

    - `info`: `path`, `file_bytes`, `start_ns`, `end_ns`, `messages`, `topics` (name -> (type,
      count)), `run` (the run record: `scene`, `dt`, `integrator`, ...), `cut_short`;
    - the exact state over time (the `ground_truth` topics where the run had sensors):
      `time_s` `(n,)`, `body_names`, `body_position` `(n, bodies, 3)` m, `body_orientation`
      `(n, bodies, 4)`; `cable_time_s` `(m,)`, `cable_names`, `cable_tension` (N),
      `cable_length`, `cable_rest_length` (m), `cable_slack` (bool): `(m, cables)`.

    `replay()` runs it again and compares every message bit for bit (`tensegrity replay`)."""

    def __init__(self, path):
        self.path = os.fspath(path)
        info, series = _native.read_bag(self.path)
        self.info = info
        self.run = info["run"]
        self.time_s = series["time_s"]
        self.body_names = series["body_names"]
        n = len(self.time_s)
        b = len(series["body_position"]) // (3 * n) if n else 0
        self.body_position = series["body_position"].reshape(n, b, 3)
        self.body_orientation = series["body_orientation"].reshape(n, b, 4)
        self.cable_time_s = series["cable_time_s"]
        self.cable_names = series["cable_names"]
        m, c = len(self.cable_time_s), len(self.cable_names)
        self.cable_tension = series["cable_tension"].reshape(m, c)
        self.cable_length = series["cable_length"].reshape(m, c)
        self.cable_rest_length = series["cable_rest_length"].reshape(m, c)
        self.cable_slack = np.array(series["cable_slack"], dtype=bool).reshape(m, c)

    def replay(self, scene=None, out=None):
        """`tensegrity replay`: a dict with `identical` (bool), `difference` (the first, in words,
        or None), `compared`, `steps`, `command_batches`, `resets`, `missing`, `cut_short`."""
        return replay(self.path, scene=scene, out=out)

    def __repr__(self):
        return f"Bag({self.path!r}: {len(self.time_s)} states, {self.info['messages']} messages)"


def step_times(scene=None, *, text=None, integrator="generalized-alpha", dt=None, rho_inf=0.8, newton_tol=None,
               steps=2000):
    """`tensegrity bench steps`: the wall time of `steps` steps of the scene after 10 untimed ones
    (in this process), as a dict: `median_s`, `mean_s`, `max_s` (s per step), `newton_per_step`,
    `factorizations_per_step`, `unknowns`, `nonzeros`, `backend`."""
    return _native.step_times(_scene_arg(scene), text=_text_arg(text), integrator=integrator,
                              dt=_number_or_none("dt", dt), rho_inf=_number_or_none("rho_inf", rho_inf),
                              newton_tol=_number_or_none("newton_tol", newton_tol), steps=_count("steps", steps))


def scaling(stages=(1, 2, 3, 4, 6, 8, 12, 16), steps=200, out=None):
    """`tensegrity bench scaling`: the step cost of the generated towers (classical, per-stage,
    helical) at each number of `stages`, `steps` steps each; writes `scaling.{csv,md,png,svg}`
    into `out` (required) and returns a `StudyResult`."""
    if out is None:
        raise TypeError("scaling needs out=, the directory its table and plot go to")
    stages = [_count("stages", s) for s in stages]
    md = _native.scaling_markdown(stages, _count("steps", steps), os.fspath(out))
    return StudyResult(md, os.fspath(out))


def reindex_bag(path):
    """`tensegrity bag reindex`: rewrites a bag whose writer was killed with every message that can
    be read (and its summary), so that it reads to the end. None when it was complete already,
    else `(messages kept, why the original stopped)`."""
    return _native.reindex_bag(os.fspath(path))


def read_bag(path):
    """The bag at `path` as a `Bag` (`ValueError` naming the path when there is none)."""
    return Bag(path)


def replay(bag, scene=None, out=None):
    """Runs the bag's run again and compares every recorded message bit for bit, as `tensegrity
    replay` does (`scene`: another scene file for it; `out`: write the re-run as a bag): a dict
    with `identical`, `difference`, `compared`, `steps`, `command_batches`, `resets`, `missing`,
    `cut_short`."""
    return _native.replay_report(os.fspath(bag), None if scene is None else os.fspath(scene),
                                 None if out is None else os.fspath(out))
