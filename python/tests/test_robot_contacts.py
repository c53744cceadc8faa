"""A robot on the ground over shared memory: each lockstep state carries the scene's contacts
(`State.contacts`, from the node's `contacts` service, published before each answer), named by
the sphere's point and its ground.

Run: `pip install ./python` then `pytest python/tests`.
"""

from pathlib import Path

import pytest

SIXBAR = Path(__file__).resolve().parents[2] / "config" / "scenes" / "sixbar.toml"
WEIGHT = 6 * 0.3 * 9.81  # six struts of 0.3 kg, N


@pytest.mark.tensegrity(scene=SIXBAR, params={"start_from_equilibrium": True}, transports=("shm",))
def test_the_robot_stands_on_three_feet_that_carry_its_weight(tensegrity_node):
    sim = tensegrity_node
    assert len(sim.names["contacts"]) == 12  # every strut end against the floor
    state = sim.lockstep(1)
    assert [c.point for c in state.contacts if c.in_contact] == ["x0.b", "y0.b", "z0.b"]
    assert all(c.other == "floor" for c in state.contacts)
    carried = sum(c.normal_force for c in state.contacts)
    assert abs(carried - WEIGHT) < 1e-6 * WEIGHT, carried
    for c in state.contacts:
        if c.in_contact:
            assert c.gap < 0 and c.normal == (0.0, 0.0, 1.0)
        else:
            assert c.gap > 0 and c.normal_force == 0.0
    # the contacts follow the answers step by step
    later = sim.lockstep(50)
    assert later.step == 51 and len(later.contacts) == 12
