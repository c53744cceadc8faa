"""A scene with sensors over shared memory: each lockstep state carries what the sensors report
(`State.measured`, from the node's `measured` service, published before each answer) beside the
exact state.

Run: `pip install ./python` then `pytest python/tests`.
"""

import math
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


@pytest.mark.tensegrity(scene=SENSORS, params={"start_from_equilibrium": True}, transports=("shm",))
def test_a_lost_position_is_flagged_and_holds_its_last_value(tensegrity_node):
    # the scene drops 1 % of its position updates: State.measured_lost flags each value held
    sim = tensegrity_node
    previous, flagged = None, 0
    for _ in range(300):
        state = sim.lockstep(1)
        lost, position = state.measured_lost["position"], state.measured["position"]
        assert state.measured_lost["tension"] == [False] and len(lost) == len(position)
        if previous is not None:
            for body in range(len(position)):
                for axis in range(3):
                    held = position[body][axis] == previous[body][axis]
                    assert lost[body][axis] == held, (body, axis, lost[body], position[body])
                    flagged += lost[body][axis]
        previous = position
    assert 0 < flagged < 30, flagged


def test_the_in_process_simulator_flags_lost_readings_too():
    from tensegrity.testing.inprocess import InProcessSimulator

    pytest.importorskip("tensegrity._native")
    sim = InProcessSimulator(SENSORS, {"start_from_equilibrium": True})
    flags = [sim.lockstep(1).measured_lost["position"] for _ in range(300)]
    assert any(any(axis for body in f for axis in body) for f in flags)


def test_a_step_counted_delay_warns_in_python():
    from tensegrity.testing.inprocess import InProcessSimulator

    pytest.importorskip("tensegrity._native")
    text = SENSORS.read_text().replace("delay_s = 0.003", "delay = 3")
    path = Path(__import__("tempfile").mkdtemp()) / "stepped.toml"
    path.write_text(text)
    with pytest.warns(FutureWarning, match="delay_s = 0.003"):
        InProcessSimulator(path)


IMU = Path(__file__).resolve().parents[2] / "config" / "examples" / "imu.toml"


@pytest.mark.tensegrity(scene=IMU, transports=("shm",))
def test_the_imu_on_a_swinging_bar_reports_its_rate_and_specific_force(tensegrity_node):
    sim = tensegrity_node
    state = sim.lockstep(480)  # 0.48 s: near the bottom of the swing
    m = state.measured
    wx, wy, wz = m["true_gyro"][0]
    assert abs(math.hypot(wx, wy) - math.sqrt(3 * 9.81)) < 0.01 and abs(wz) < 1e-12  # sqrt(3 g / L)
    assert abs(m["true_accelerometer"][0][2] + 2.5 * 9.81) < 0.1  # 2.5 g towards the pin
    # what the sensors report: the truth with 0.01 rad/s and 0.05 m/s^2 of noise, held at 200 Hz
    assert abs(m["accelerometer"][0][2] - m["true_accelerometer"][0][2]) < 0.5
    assert 0 < abs(m["gyro"][0][0] - wx) < 0.2


@pytest.mark.tensegrity(scene=IMU, paused=False, transports=("dds",))
def test_the_imu_is_published_measured_and_true_over_dds(tensegrity_node):
    sim = tensegrity_node
    measured, truth = sim.reader("~/imu"), sim.reader("~/ground_truth/imu")
    m, t = sim.next(measured), sim.next(truth)
    assert m is not None and t is not None, "IMU states arrive"
    assert list(m.name) == ["bar"] and len(m.angular_velocity) == 1 and len(t.specific_force) == 1
    assert math.isfinite(m.specific_force[0].z) and math.isfinite(t.angular_velocity[0].x)
