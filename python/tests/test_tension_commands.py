"""Tension commands for a winch motor (`config/examples/tensioner.toml`): the motor holds its line
force at the commanded tension and the node settles where the spring carries it, in lockstep over
shared memory (`command(..., tension=...)`) and in real time over DDS (`~/tension_commands`).

Run: `pip install ./python` then `pytest python/tests`.
"""

from pathlib import Path

import pytest

from tensegrity.testing import command, msgs

TENSIONER = Path(__file__).resolve().parents[2] / "config" / "examples" / "tensioner.toml"
SETTLED_X = 2.0 - 0.9 * (1.0 + 30.0 / 1000.0)  # the spring carries 30 N


@pytest.mark.tensegrity(scene=TENSIONER, params={"start_from_equilibrium": True}, transports=("shm",))
def test_a_tension_command_in_lockstep_settles_the_spring_at_that_tension(tensegrity_node):
    sim = tensegrity_node
    spring = sim.cable_index("spring")
    state = sim.lockstep(1)
    assert state.cable_tension[spring] > 100.0  # the rope holds the node near x = 1 m
    state = sim.lockstep(3000, [command("tensioner", tension=30.0)])  # 3 s
    assert abs(state.cable_tension[spring] - 30.0) < 1e-6
    assert abs(state.body_position[1][0] - SETTLED_X) < 1e-6
    # above the stall tension (100 N) or with a rest length too: refused, the node goes on
    for careless in (command("tensioner", tension=150.0), command("tensioner", tension=10.0, rest_length=1.0)):
        with pytest.raises(Exception, match="tension"):
            sim.lockstep(1, [careless])
    after = sim.lockstep(1)
    assert after.commands_rejected == 2 and abs(after.cable_tension[spring] - 30.0) < 1e-6


@pytest.mark.tensegrity(
    scene=TENSIONER,
    paused=False,
    params={"start_from_equilibrium": True, "state_publish_rate": 100},
    transports=("dds",),
)
def test_a_tension_command_over_dds_settles_the_spring_at_that_tension(tensegrity_node):
    sim = tensegrity_node  # playing in real time; cable states every 10 ms of sim time
    states = sim.reader("~/cable_states")
    tensions = sim.writer("~/tension_commands")
    t, m = 0.0, None
    while t < 2.0:
        m = sim.next(states)
        assert m is not None, "cable states arrive"
        t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
        tensions.write(msgs.TensionCommand(name=["tensioner"], tension=[30.0]))
    spring = m.name.index("spring")
    assert abs(m.tension[spring] - 30.0) < 1e-3, m.tension
