"""The clustered tensegrity simulator as a Python library: arrays in and out (numpy float64, SI
units: m, N, s, kg, J, Hz).

    import tensegrity
    eq = tensegrity.statics("bundled:prism3")        # the equilibrium: eq.tensions, N
    modes = tensegrity.modes("bundled:prism3", count=3)
    path = tensegrity.quasi_static("bundled:prism3")  # path["time_s"], path.to_pandas()
    run = tensegrity.dynamic("bundled:prism3", duration=0.5)
    with tensegrity.Simulator("bundled:prism3") as sim:
        s = sim.step(100, {"ring_winch": {"rate": -0.01}})

A scene is a file path, `"bundled:NAME"`, None (the bundled prism3), or TOML text given as
`text=` (`tensegrity.generate(...)` writes one). `tensegrity.envs` has the Gymnasium
environments (`pip install './python[gym]'`), `tensegrity.testing` the launch-free test kit for
controllers of a `tensegrity_node` (its pytest plugin is registered on install).

Errors: `SceneError` (a `ValueError`: `file`, `line`, `field`, `reason`), `NoEquilibrium` (a
`RuntimeError`: `iterations`, `residual_n`, `stop_reason`), `PhysicsFailure` (a step failed),
`CommandRefused` (a `ValueError`: a command the simulator refused; it stays usable).
"""

from ._native import NoEquilibrium, PhysicsFailure, SceneError, __version__
from .library import (
    Bag,
    DynamicRun,
    Modes,
    QuasiStaticPath,
    SceneCheck,
    Statics,
    StudyResult,
    Table,
    check,
    dynamic,
    field_reference,
    generate,
    modes,
    quasi_static,
    read_bag,
    reindex_bag,
    replay,
    scaling,
    statics,
    step_times,
    study,
    work_precision,
)
from .simulator import CommandRefused, Simulator, SimState

__all__ = [
    "__version__",
    "check",
    "statics",
    "modes",
    "quasi_static",
    "dynamic",
    "generate",
    "field_reference",
    "study",
    "work_precision",
    "step_times",
    "scaling",
    "read_bag",
    "replay",
    "reindex_bag",
    "Bag",
    "StudyResult",
    "Simulator",
    "SimState",
    "SceneCheck",
    "Statics",
    "Modes",
    "Table",
    "QuasiStaticPath",
    "DynamicRun",
    "SceneError",
    "NoEquilibrium",
    "PhysicsFailure",
    "CommandRefused",
]
