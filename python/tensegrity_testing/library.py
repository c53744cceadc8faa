"""The library from Python, arrays out: a scene's static equilibrium (`statics`), its natural
modes (`modes`) and its quasi-static deployment path (`quasi_static`), with the numbers
`tensegrity statics --json`, `modes --json` and `deploy --quasi-static` write, to the bit (they
call the same library code). Needs the extension
(`pip install ./python/native`).

A scene is a file path, `"bundled:NAME"`, None (the bundled prism3), or TOML text given as
`text=`. A scene that cannot be read or is invalid raises `SceneError` (a `ValueError` with
`file`, `line`, `field` and `reason`); a scene with a body nothing holds raises `ValueError`; a
solve that ends without an equilibrium raises `NoEquilibrium` (a `RuntimeError` with
`iterations`, `residual_n`, `stop_reason`). Units are SI: m, N, J, Hz.

    from tensegrity_testing.library import statics, modes
    eq = statics("bundled:prism3")
    eq.tensions                      # numpy float64, N, in eq.cable_names order
    modes("bundled:prism3", count=3).frequencies_hz
"""

import json
import os

import numpy as np
import tensegrity_native as _native
from tensegrity_native import NoEquilibrium, SceneError

__all__ = ["statics", "modes", "quasi_static", "field_reference", "Statics", "Modes", "QuasiStaticPath", "SceneError", "NoEquilibrium"]


def _scene_arg(scene):
    if scene is None:
        return None
    if isinstance(scene, os.PathLike):
        return os.fspath(scene)
    if not isinstance(scene, str):
        raise TypeError(f"scene must be a path, 'bundled:NAME' or None, got {type(scene).__name__}")
    return scene


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
    if text is not None and not isinstance(text, str):
        raise TypeError(f"text must be the scene's TOML as a str, got {type(text).__name__}")
    return Statics(json.loads(_native.statics_json(_scene_arg(scene), text=text)))


class Modes:
    """Natural modes at the equilibrium: `modes` (the `modes --json` list of dicts: every
    zero-frequency mode, then the lowest `count` others), and as arrays in that order `index`
    (1-based among all modes), `frequencies_hz` (Hz; 0 for zero and unstable modes),
    `omega_squared` (1/s^2) and `zero` (bool)."""

    def __init__(self, listed):
        self.modes = listed
        self.index = np.array([m["index"] for m in listed], dtype=np.int64)
        self.frequencies_hz = np.array([m["frequency_hz"] for m in listed], dtype=np.float64)
        self.omega_squared = np.array([m["omega_squared"] for m in listed], dtype=np.float64)
        self.zero = np.array([m["zero_frequency"] for m in listed], dtype=bool)

    def __len__(self):
        return len(self.modes)

    def __repr__(self):
        return f"Modes({len(self.modes)} listed, lowest vibrating {self.frequencies_hz[~self.zero][:3]} Hz)"


def modes(scene=None, count=10, *, text=None):
    """The natural modes of `scene` (or of the TOML `text`) at its equilibrium: `Modes`, with
    every zero-frequency mode and the lowest `count` vibrating ones."""
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 0:
        raise TypeError(f"count must be a non-negative int, got {count!r}")
    if text is not None and not isinstance(text, str):
        raise TypeError(f"text must be the scene's TOML as a str, got {type(text).__name__}")
    return Modes(json.loads(_native.modes_json(_scene_arg(scene), int(count), text=text)))


class QuasiStaticPath:
    """The equilibrium path along a scene's deployment schedule, one row per load step (and per
    point traced by arc length past a limit point): `csv` (the text `tensegrity deploy
    --quasi-static --out -` writes, byte for byte), `columns` (the CSV's header names) and
    `data` (column name -> numpy array: float64 for numbers, str for the `point` column, which
    says `load`, `arc` or `snap`). `path["time_s"]` is `path.data["time_s"]`; `to_pandas()` is a
    DataFrame (with pandas installed)."""

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
        """The path as a pandas DataFrame (pandas must be installed)."""
        import pandas as pd

        return pd.DataFrame({name: self.data[name] for name in self.columns})

    def __repr__(self):
        return f"QuasiStaticPath({len(self)} rows, {len(self.columns)} columns)"


def quasi_static(scene=None, steps=None, *, text=None):
    """The quasi-static deployment of `scene` (or of the TOML `text`) along its schedule, in
    `steps` load steps (default the scene's): a `QuasiStaticPath`. A path that ends without an
    equilibrium (a robot tipping over) raises `NoEquilibrium`."""
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, (int, np.integer))):
        raise TypeError(f"steps must be an int, got {steps!r}")
    if text is not None and not isinstance(text, str):
        raise TypeError(f"text must be the scene's TOML as a str, got {type(text).__name__}")
    return QuasiStaticPath(_native.quasi_static_csv(_scene_arg(scene), None if steps is None else int(steps),
                                                   text=text))


def field_reference():
    """The scene-file field reference (every table and field: format, unit, default, range) as
    the Markdown table `tensegrity fields` prints."""
    return _native.field_reference()
