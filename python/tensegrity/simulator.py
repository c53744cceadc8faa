"""The simulator stepped from Python, state out as numpy arrays: `Simulator` is the node's core
(the same command checks, seeded resets, sensors and bag recording as `tensegrity_node`) in this
process, with no transport:

    import tensegrity
    with tensegrity.Simulator("bundled:prism3") as sim:
        s = sim.step(100, {"ring_winch": {"rate": -0.01}})
        s.time, s.cable_tension                 # s, N (numpy float64, in sim.cable_names order)

`step` applies commands at the next step boundary and takes `steps` physics steps. A command
names an actuator and gives a `rest_length` (m), a `rate` (m/s) or, for a winch, a `tension`
(N); the same command as the node's `~/commands`. A command the node would refuse (an unknown
actuator, a NaN, a value out of the actuator's limits) raises `CommandRefused` and takes no
step: the simulator stays usable. A step that fails even at the smallest sub-step raises
`PhysicsFailure`, and the simulator stays at its last good state until `reset`.

The arrays of a `SimState` are read-only views into the state's bytes as the core wrote them
(no copy per array); take `.copy()` to keep a changed one.
"""

import math

import numpy as np

from . import _native

__all__ = ["Simulator", "SimState", "CommandRefused"]


class CommandRefused(ValueError):
    """A command the simulator refused (the node's reason); no step was taken."""


def _shm():
    from .testing import shm

    return shm


class SimState:
    """The state after a step (SI units; arrays in the order of the simulator's names):

    - `time` (s), `step`, `faulted`;
    - `body_position` `(bodies, 3)` m, `body_orientation` `(bodies, 4)` unit quaternions
      `[x, y, z, w]`;
    - `cable_tension` (N), `cable_length`, `cable_rest_length` (m), `cable_slack` (bool):
      `(cables,)`;
    - `actuator_rest_length` (m), `actuator_rate` (m/s): `(actuators,)`.
    """

    def __init__(self, sample):
        shm = _shm()
        S = shm.StateSample

        def view(field, count, dtype=np.float64, shape=None):
            arr = np.frombuffer(sample, dtype=dtype, count=count, offset=getattr(S, field).offset)
            return arr if shape is None else arr.reshape(shape)

        def scalar(field, dtype):
            return view(field, 1, dtype)[0].item()

        b, c, a = (scalar(f, np.uint32) for f in ("body_count", "cable_count", "actuator_count"))
        self.time = scalar("time", np.float64)
        self.step = scalar("step", np.uint64)
        self.faulted = bool(scalar("faulted", np.uint8))
        self.commands_rejected = scalar("commands_rejected", np.uint64)

        self.body_position = view("body_position", 3 * b, shape=(b, 3))
        self.body_orientation = view("body_orientation", 4 * b, shape=(b, 4))
        self.cable_tension = view("cable_tension", c)
        self.cable_length = view("cable_length", c)
        self.cable_rest_length = view("cable_rest_length", c)
        self.cable_slack = view("cable_slack", c, dtype=np.uint8).astype(bool)
        self.actuator_rest_length = view("actuator_rest_length", a)
        self.actuator_rate = view("actuator_rate", a)

    def __repr__(self):
        return f"SimState(t={self.time} s, step {self.step}{', faulted' if self.faulted else ''})"


def _command_entries(commands, actuator_names):
    """`{"name": {"rate": x}}`, `{"name": x}` (a rate), or `[command(...), ...]` as entries."""
    shm = _shm()
    if commands is None:
        return []
    if isinstance(commands, dict):
        entries = []
        for name, value in commands.items():
            if not isinstance(name, (str, int)) or isinstance(name, bool):
                raise TypeError(f"an actuator is named by its name or index, got {name!r}")
            if isinstance(name, str) and name not in actuator_names:
                raise CommandRefused(f"no actuator {name!r} (actuators: {', '.join(actuator_names) or 'none'})")
            if isinstance(value, dict):
                unknown = set(value) - {"rest_length", "rate", "tension"}
                if unknown:
                    raise TypeError(f"{name}: a command takes rest_length, rate or tension, not {sorted(unknown)}")
                fields = value
            else:
                fields = {"rate": value}
            for key, x in fields.items():
                if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
                    raise TypeError(f"{name}: {key} must be a number, got {x!r}")
                if not math.isfinite(x):
                    raise CommandRefused(f"{name}: {key} must be finite, got {x}")
            entries.append(shm.entry(name, **{k: float(v) for k, v in fields.items()}))
        return entries
    return list(commands)


class Simulator:
    """A scene simulated in this process (module docs). `scene`: a file, `"bundled:NAME"` or
    None (the bundled prism3); `params`: the node's parameters by name (`physics_dt`,
    `integrator`, `record` for a bag directory, ...). Always paused: it steps only when told."""

    def __init__(self, scene=None, params=None):
        from .testing.node import _param_text

        if scene is not None and not isinstance(scene, (str,)) and not hasattr(scene, "__fspath__"):
            raise TypeError(f"scene must be a path, 'bundled:NAME' or None, got {type(scene).__name__}")
        if params is not None and not isinstance(params, dict):
            raise TypeError(f"params must be a dict of node parameters, got {type(params).__name__}")
        text = {k: _param_text(v) for k, v in (params or {}).items()}
        self._sim = _native.Simulator(None if scene is None else str(scene), text)
        names = self._sim.names()
        self.names = names
        self.scene_name = names["scene_name"]
        self.physics_dt = names["physics_dt"]
        self.body_names = list(names["body_names"])
        self.cable_names = list(names["cable_names"])
        self.actuator_names = list(names["actuator_names"])

    def _live(self):
        if self._sim is None:
            raise RuntimeError("the simulator is closed")
        return self._sim

    def step(self, steps=1, commands=None, *, reset=False, seed=None):
        """Applies `commands` (a dict actuator name -> rate in m/s, or -> a dict of `rest_length`,
        `rate`, `tension`; or `tensegrity.testing.command` entries) at the next step boundary,
        takes `steps` physics steps (`steps=0`: apply only) and returns the `SimState` after
        them; with `reset`, first back to the start (the episode drawn from `seed`)."""
        sim = self._live()
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0:
            raise TypeError(f"steps must be a non-negative int, got {steps!r}")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
            raise TypeError(f"seed must be a non-negative int, got {seed!r}")
        packed = _shm().packed_commands(_command_entries(commands, self.actuator_names))
        try:
            sim.lockstep(int(steps), packed, bool(reset), None if seed is None else int(seed))
        except _native.CommandRefused as e:
            raise CommandRefused(str(e)) from None
        return self.state()

    def reset(self, seed=None):
        """Back to the start (the scene's randomization drawn from `seed`); the `SimState` there."""
        return self.step(0, reset=True, seed=seed)

    def state(self):
        """The `SimState` now."""
        return SimState(self._live().state_sample())

    def close(self):
        """Closes the bag being recorded (with `record`); the simulator cannot step afterwards."""
        if self._sim is not None:
            self._sim.close()
            self._sim = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self):
        return f"Simulator({self.scene_name!r}, dt={self.physics_dt} s)"
