"""The README's Python examples: a proportional controller drives the bundled prism3's ring cable
to a target tension, in lockstep (shared memory, tight tolerance) and in real time (DDS, looser);
lockstep results are bit-identical across two runs, one of them under a CPU hog on every core.

Run: `pip install ./python` then `pytest python/tests` (tensegrity_node from $TENSEGRITY_NODE,
PATH or this checkout's target/).
"""

import os
import subprocess

import pytest

from tensegrity.testing import command, msgs

TARGET = 300.0  # N, the ring starts at 100 N
GAIN = 2e-3  # winch rate per newton of tension error, m/s/N
PERIOD = 10  # steps (10 ms) between controller updates


def lockstep_run(sim, periods=150):
    ring = sim.cable_index("ring")
    state = sim.lockstep(0)  # the initial state
    trajectory = [state]
    for _ in range(periods):
        rate = GAIN * (state.cable_tension[ring] - TARGET)
        state = sim.lockstep(PERIOD, [command("ring_winch", rate=rate)])
        trajectory.append(state)
    return trajectory


# README example (Python, lockstep): start here.
def test_lockstep_controller_reaches_its_target_tension(tensegrity_node):
    sim = tensegrity_node  # bundled prism3, paused: the test owns time
    ring = sim.cable_index("ring")
    state = sim.lockstep(0)
    for _ in range(150):
        rate = GAIN * (state.cable_tension[ring] - TARGET)  # proportional winch rate
        state = sim.lockstep(PERIOD, [command("ring_winch", rate=rate)])
    assert state.step == 1500
    assert abs(state.cable_tension[ring] - TARGET) < 0.5


# README example end.


# README example (Python, real time): start here.
@pytest.mark.tensegrity(paused=False, params={"state_publish_rate": 100})
def test_real_time_controller_reaches_its_target_tension(tensegrity_node):
    sim = tensegrity_node  # playing in real time; states over DDS every 10 ms of sim time
    states = sim.reader("~/cable_states")
    commands = sim.writer("~/actuator_commands")
    t = 0.0
    while t < 2.0:
        m = sim.next(states)
        assert m is not None, "cable states arrive"
        ring = m.name.index("ring")
        t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
        rate = GAIN * (m.tension[ring] - TARGET)
        commands.write(msgs.ActuatorCommand(name=["ring_winch"], rate=[rate]))
    assert abs(m.tension[ring] - TARGET) < 0.02 * TARGET


# README example end.


def test_lockstep_is_bit_identical_across_runs_and_under_load(tensegrity_nodes):
    quiet = lockstep_run(tensegrity_nodes())
    hogs = [subprocess.Popen(["sh", "-c", "while :; do :; done"]) for _ in range(os.cpu_count() or 2)]
    try:
        loaded = lockstep_run(tensegrity_nodes())
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    assert quiet == loaded  # dataclasses of floats: equal means bit-identical (no NaN is published)


def test_a_careless_command_is_refused_and_the_node_goes_on(tensegrity_node):
    sim = tensegrity_node
    before = sim.lockstep(1)
    with pytest.raises(Exception, match="finite|rejected|refused"):
        sim.lockstep(1, [command("ring_winch", rest_length=float("nan"))])
    after = sim.lockstep(1)
    assert after.step == before.step + 1 and after.commands_rejected == 1


def test_a_bad_scene_is_reported_with_its_exit_status(tensegrity_nodes, tmp_path):
    from tensegrity.testing import NodeFailed

    bad = tmp_path / "bad.toml"
    bad.write_text("name = 3\n")
    with pytest.raises(NodeFailed) as e:
        tensegrity_nodes(scene=bad)
    assert e.value.status == 3 and "bad.toml" in e.value.stderr
    with pytest.raises(NodeFailed) as e:
        tensegrity_nodes(params={"physics_dt": -1})
    assert e.value.status == 2 and "physics_dt" in e.value.stderr


def test_a_lockstep_request_with_undefined_flags_is_refused_and_steps_nothing(tensegrity_node):
    # a hand-made client's careless request: SEEDED without RESET, and an unknown bit
    import iceoryx2 as iox2

    from tensegrity.testing import shm

    sim = tensegrity_node
    client = sim.shm
    before = sim.lockstep(0).step
    for flags in (shm.LOCKSTEP_SEEDED, 8):
        request = client.lockstep_client.loan_uninit()
        payload = request.payload().contents
        payload.steps, payload.flags, payload.reserved, payload.seed = 1, flags, 0, 0
        payload.command.count = 0
        pending = request.assume_init().send()
        client.wake_node.notify_with_custom_event_id(iox2.EventId.new(shm.EVENT_LOCKSTEP))
        answer = shm.Answer(client._wait(pending.receive, 10.0))
        assert answer.payload.result != shm.RESULT_OK
        assert "flags" in shm.text(answer.payload.message)
        del answer
    assert sim.lockstep(0).step == before
