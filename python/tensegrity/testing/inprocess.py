"""The simulator in this Python process: `InProcessSimulator` wraps `tensegrity._native.Simulator`
(the library's Python extension, part of `pip install ./python`) behind the lockstep part of
`TensegrityNode` (`names`, `lockstep`, `lockstep_begin`/`lockstep_end`, `stop`), so code written
for a paused node runs on it unchanged, without a node process and without a round trip between
processes:

    from tensegrity.testing.inprocess import InProcessSimulator
    from tensegrity.testing import command
    sim = InProcessSimulator("bundled:prism3", params={"record": "run_bag"})
    state = sim.lockstep(10, [command("ring_winch", rate=-0.01)])
    print(state.time, state.cable_tension)
    sim.stop()                                   # closes the bag

It is the same node core as the node's (commands checked the same way, seeded resets, sensors,
bags), so the same requests give the same `State` to the bit. What it does not have is what
needs a process of its own: DDS and shared-memory peers, real-time pacing, crash isolation.
"""

import warnings

from . import shm
from .node import state_of


def available():
    """True when the extension `tensegrity._native` can be imported (it is part of the package:
    `pip install ./python` builds it)."""
    try:
        from .. import _native  # noqa: F401
    except ImportError:
        return False
    return True


def act_all(sims, actions, steps):
    """`tensegrity._native.act_all`: one learning step on each of `sims` (`Simulator`s with a
    task), in parallel; a list of `act` tuples, or the `PhysicsFailure` of a simulator that
    failed."""
    from .. import _native

    return _native.act_all(sims, actions, steps)


class InProcessSimulator:
    """`tensegrity._native.Simulator` with `TensegrityNode`'s lockstep interface (module docs).

    scene: a scene file, `bundled:NAME`, or None (the bundled prism3); params: node parameters
    by name (`-p name:=value` of the node; `record` writes a bag). Always paused."""

    def __init__(self, scene=None, params=None, **_ignored):
        from .. import _native
        from .node import _param_text

        text = {k: _param_text(v) for k, v in (params or {}).items()}
        self.sim = _native.Simulator(None if scene is None else str(scene), text)
        self.PhysicsFailure = _native.PhysicsFailure
        self.names = self.sim.names()
        self.timeout = None
        for line in self.sim.delay_warnings():
            warnings.warn(line, FutureWarning if "counts physics steps" in line else UserWarning, stacklevel=2)

    def lockstep(self, steps, commands=(), reset=False, seed=None):
        """Applies `commands` (`command(...)` entries) at the next boundary, takes `steps` steps
        and returns the `State` after them; with `reset`, resets first (the episode drawn from
        `seed` when given). A rejected command or a failed step raises `shm.LockstepRefused`,
        as the node does."""
        try:
            self.sim.lockstep(steps, shm.packed_commands(commands), reset, seed)
        except self.PhysicsFailure as e:
            raise shm.LockstepRefused(str(e)) from None
        return self.state()

    def state(self):
        """The `State` now (with contacts and what the sensors report, where the scene has them)."""
        s = shm.StateSample.from_buffer_copy(self.sim.state_sample())
        contacts = self.sim.contacts_sample()
        measured = self.sim.measured_sample()
        return state_of(
            s,
            self.names,
            None if contacts is None else shm.ContactsSample.from_buffer_copy(contacts),
            None if measured is None else shm.MeasuredSample.from_buffer_copy(measured),
        )

    def lockstep_begin(self, steps, commands=(), reset=False, seed=None):
        """`lockstep` at once (in process nothing runs meanwhile); `lockstep_end` hands over its
        `State` or raises its failure."""
        try:
            return self.lockstep(steps, commands, reset, seed)
        except Exception as e:  # handed over by lockstep_end
            return e

    def lockstep_end(self, pending):
        """The `State` of the `lockstep_begin` call that returned `pending`."""
        if isinstance(pending, Exception):
            raise pending
        return pending

    def stop(self, timeout=None):
        """Closes the bag being recorded (with `record`); returns 0, as a node stopped cleanly."""
        if self.sim is not None:
            self.sim.close()
            self.sim = None
        return 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
