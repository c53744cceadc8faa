"""A scene with sensors over shared memory: each lockstep state carries what the sensors report
(`State.measured`, from the node's `measured` service, published before each answer) beside the
exact state.

Run: `pip install ./python` then `pytest python/tests`.
"""

from pathlib import Path

import pytest

SENSORS = Path(__file__).resolve().parents[2] / "config" / "examples" / "sensors.toml"


@pytest.mark.tensegrity(scene=SENSORS, params={"start_from_equilibrium": True}, transports=("shm",))
def test_the_tension_sensor_is_noisy_and_held_between_its_updates(tensegrity_node):
    sim = tensegrity_node
    rope = sim.cable_index("rope")
    errors, readings = [], []
    for _ in range(100):
        state = sim.lockstep(1)
        assert abs(state.cable_tension[rope] - 98.1) < 1e-6  # the truth: the load at rest
        readings.append(state.measured["tension"][rope])
        errors.append(readings[-1] - state.cable_tension[rope])
        assert abs(state.measured["position"][1][2] - state.body_position[1][2]) < 0.01
    # 100 Hz at 1 ms: ten updates of sigma 0.5 N in 100 steps, each held for ten steps
    changes = sum(1 for a, b in zip(readings, readings[1:]) if a != b)
    assert 8 <= changes <= 10, changes
    assert any(abs(e) > 0.05 for e in errors) and all(abs(e) < 3.0 for e in errors)
