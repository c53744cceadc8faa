"""The Gymnasium environments (`tensegrity.envs`), with the simulator in process
(`tensegrity._native`) and as a node over shared memory: both pass Gymnasium's own checker, the
same seed gives the same episodes to the bit (scene randomization included) and the two backends
give each other's episodes to the bit, a vector environment's results equal the same environments
stepped one by one, a recorded run of seeded episodes replays bit for bit, and a short random
search improves the return on the tension-target task (the environment is learnable, not only
valid).

Run: `pip install './python[gym]'` then `pytest python/tests`.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

gym = pytest.importorskip("gymnasium")
np = pytest.importorskip("numpy")

from gymnasium.utils.env_checker import check_env  # noqa: E402

from tensegrity.testing import command  # noqa: E402
from tensegrity.envs import TensegrityEnv, make_vector_env  # noqa: E402
from tensegrity.testing.inprocess import InProcessSimulator  # noqa: E402
from tensegrity.testing.shm import LockstepRefused  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BACKENDS = ["inprocess", "node"]


def randomized_with_a_winch(tmp_path):
    """config/examples/randomized.toml (EA, mass and rest length drawn per episode) with an
    ideal winch on its rope."""
    text = (ROOT / "config" / "examples" / "randomized.toml").read_text()
    text = text.replace("seed = 11\n", 'seed = 11\nper = "reset"\n')
    text += ('\n[[actuators]]\nname = "winch"\ncable = "rope"\nmin_rest_length = 0.5\n'
             "max_rest_length = 1.5\nmax_rate = 0.1\n")
    path = tmp_path / "randomized_winch.toml"
    path.write_text(text)
    return path


def run(env, seed, actions):
    """Observations (and rewards) of an episode from `reset(seed=seed)` under `actions`."""
    obs, info = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        out += [obs, np.array([reward])]
    return np.concatenate(out), info["episode_seed"]


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_bundled_environment_passes_gymnasiums_checker(backend):
    env = gym.make("tensegrity/Prism3Tension-v0", backend=backend)
    try:
        assert env.unwrapped.backend == backend
        check_env(env.unwrapped, skip_render_check=True)
        obs, _ = env.reset(seed=0)
        assert env.observation_space.contains(obs)
        # a careless action is clipped to the space, a NaN refused
        obs, reward, *_ = env.step(np.array([7.0]))
        assert np.isfinite(reward) and env.observation_space.contains(obs)
        with pytest.raises(ValueError, match="finite"):
            env.step(np.array([np.nan]))
        # and the environment goes on
        obs, reward, *_ = env.step(np.array([0.0]))
        assert np.isfinite(reward) and env.observation_space.contains(obs)
    finally:
        env.close()


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_rolling_robot_environment_passes_gymnasiums_checker(backend):
    env = gym.make("tensegrity/SixbarRoll-v0", backend=backend)
    try:
        check_env(env.unwrapped, skip_render_check=True)
        obs, _ = env.reset(seed=0)
        # hauling in every winch part way: the robot moves, the reward says how far toward the goal
        obs, reward, terminated, truncated, info = env.step(np.full(24, -0.5))
        assert np.all(np.isfinite(obs)) and np.isfinite(reward) and abs(reward) < 0.5
    finally:
        env.close()


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_same_seed_gives_the_same_episodes_to_the_bit(tmp_path, backend):
    scene = randomized_with_a_winch(tmp_path)
    actions = np.random.default_rng(7).uniform(-1.0, 1.0, size=(30, 1))
    a, b = (TensegrityEnv(scene, action_period=5, backend=backend) for _ in range(2))
    try:
        first, seed_a = run(a, 42, actions)
        second, seed_b = run(b, 42, actions)
        assert seed_a == seed_b and np.array_equal(first, second)
        # the next episode of each (no seed: drawn from the seeded generator) agrees too
        assert np.array_equal(run(a, None, actions)[0], run(b, None, actions)[0])
        # another seed draws another model: other tensions from the first observation on
        other, seed_c = run(b, 43, actions)
        assert seed_c != seed_a and not np.array_equal(first[:1], other[:1])
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize("vectorization,backend", [("parallel", "inprocess"), ("parallel", "node"), ("async", "auto")])
def test_a_vector_environment_equals_its_environments_stepped_one_by_one(vectorization, backend):
    # episodes of 6 actions: the 10 steps cross an autoreset (next-step mode: the step after the
    # end resets, reward 0)
    kwargs = {"actuators": ["ring_winch"], "target_tension": {"ring": 300.0}, "max_episode_steps": 6}
    actions = np.random.default_rng(3).uniform(-0.2, 0.2, size=(10, 2, 1))
    vec = make_vector_env(2, vectorization=vectorization, backend=backend, **kwargs)
    try:
        obs, _ = vec.reset(seed=[11, 12])
        together = [obs]
        for a in actions:
            obs, reward, *_ = vec.step(a)
            together += [obs, reward[:, None]]
    finally:
        vec.close()
    for k, seed in enumerate([11, 12]):
        env = TensegrityEnv(**kwargs)
        try:
            alone, _ = run(env, seed, actions[:6, k])
            # then the reset step (its reward 0) and three more actions
            obs, _ = env.reset()
            rest = [obs, np.array([0.0])]
            for a in actions[7:, k]:
                obs, reward, *_ = env.step(a)
                rest += [obs, np.array([reward])]
        finally:
            env.close()
        mine = np.concatenate([t[k] for t in together])
        assert np.array_equal(mine, np.concatenate([alone] + rest)), f"environment {k}"


@pytest.mark.parametrize("backend", BACKENDS)
def test_recorded_seeded_episodes_replay_bit_for_bit(tmp_path, backend):
    scene = randomized_with_a_winch(tmp_path)
    bag = tmp_path / "episodes"
    env = TensegrityEnv(scene, action_period=5, params={"record": str(bag)}, backend=backend)
    try:
        for seed in (5, None):
            env.reset(seed=seed)
            for _ in range(10):
                env.step(np.array([0.5]))
    finally:
        env.close()
    cli = Path(os.environ.get("TENSEGRITY_NODE", "tensegrity_node")).with_name("tensegrity")
    out = subprocess.run([str(cli), "replay", str(bag)], capture_output=True, text=True)
    assert out.returncode == 0 and "identical" in out.stdout, out.stdout + out.stderr


def test_the_roll_goal_task_is_valid_and_its_baseline_roller_reaches_goals_three_rolls_away():
    # SixbarRollGoal-v0 (the learning task of benches/learn_roll.py): one hauled cable per action;
    # the kit's roller reaches a goal 1.5 m away (within 0.3 m: at least three rolls of about 0.44 m) on the
    # nominal robot and on a randomized one seen through noisy sensors; random cables do not
    from tensegrity.envs import SixbarRollGoalEnv

    env = gym.make("tensegrity/SixbarRollGoal-v0")
    try:
        check_env(env.unwrapped, skip_render_check=True)
    finally:
        env.close()
    for randomize in (False, True):
        env = SixbarRollGoalEnv(randomize=randomize)
        try:
            obs, info = env.reset(seed=3)
            assert obs.shape == (37,) and abs(obs[-1] - 1.5) < 1e-9, obs
            # the goal lies along +x of the observation's frame: the ends' centre is the origin
            assert np.allclose(obs[:-1].reshape(12, 3).mean(axis=0), 0.0, atol=1e-12)
            rolls, done = 0, False
            while not done:
                obs, reward, terminated, truncated, info = env.step(env.roller_action())
                rolls += 1
                assert reward > 0.0, f"roll {rolls} lost {-reward} dm"
                done = terminated or truncated
            assert info["reached"] and 3 <= rolls <= 8 and "failure" not in info, (rolls, info)
            assert info["time"] == pytest.approx(1.5 * rolls, abs=1e-9)
            # careless actions are refused, and the episode goes on
            for bad in (24, -1, 2.5, "3", np.nan):
                with pytest.raises(ValueError, match="cable's index"):
                    env.step(bad)
            obs, reward, *_ = env.step(np.int64(0))
            assert np.all(np.isfinite(obs)) and np.isfinite(reward)
        finally:
            env.close()
    # the same seed, the same goal and robot: a random policy's episode repeats to the bit; it
    # does not get there
    episodes = []
    for _ in range(2):
        env = SixbarRollGoalEnv(randomize=True, max_actions=6)
        try:
            obs, _ = env.reset(seed=11)
            out, rng, done = [obs], np.random.default_rng(0), False
            while not done:
                obs, reward, terminated, truncated, info = env.step(int(rng.integers(24)))
                out += [obs, [reward]]
                done = terminated or truncated
            assert not info["reached"]
            episodes.append(np.concatenate(out))
        finally:
            env.close()
    assert np.array_equal(*episodes)
    for bad in ({"distance": 0.0}, {"reach": float("nan")}, {"haul": 0.0}, {"max_actions": 0},
                {"haul_fraction": 1.5}, {"max_actions": 2.0}):
        with pytest.raises(ValueError):
            SixbarRollGoalEnv(**bad)


def test_a_short_random_search_learns_the_tension_task():
    # a linear policy on the ring's relative tension error, u = th0 e + th1, improved by random
    # search: 10 rounds of a 40-action episode (4000 physics steps in all)
    env = TensegrityEnv(actuators=["ring_winch"], target_tension={"ring": 300.0}, max_episode_steps=40)
    ring = env.node.names["cable_names"].index("ring")

    def episode(theta):
        obs, _ = env.reset(seed=0)
        total = 0.0
        for _ in range(40):
            error = (obs[ring] - 300.0) / 300.0
            obs, reward, terminated, truncated, _ = env.step(np.array([theta[0] * error + theta[1]]))
            total += reward
            if terminated or truncated:
                break
        return total

    try:
        rng = np.random.default_rng(1)
        theta = np.zeros(2)
        start = best = episode(theta)
        for _ in range(9):
            trial = theta + rng.normal(0.0, 0.1, size=2)
            r = episode(trial)
            if r > best:
                theta, best = trial, r
    finally:
        env.close()
    # doing nothing leaves the ring at 100 N (a return of about -0.67 per action)
    assert best > start + 0.25 * abs(start), (start, best, theta)


def test_observations_can_be_what_the_sensors_report_seeded_per_episode():
    # config/examples/sensors.toml: a load at rest on a winch's rope, its tension sensed with 0.5 N
    # of noise at 100 Hz; an action every 10 ms sees a fresh, noisy reading
    scene = ROOT / "config" / "examples" / "sensors.toml"
    kwargs = {"action_period": 10, "params": {"start_from_equilibrium": True}}
    sensed, exact = TensegrityEnv(scene, measured=True, **kwargs), TensegrityEnv(scene, **kwargs)
    try:
        still = np.zeros((20, 1))
        noisy, _ = run(sensed, 4, still)
        again, _ = run(sensed, 4, still)
        other, _ = run(sensed, 5, still)
        truth, _ = run(exact, 4, still)
    finally:
        sensed.close()
        exact.close()
    assert np.array_equal(noisy, again), "the same seed, the same noise"
    assert not np.array_equal(noisy, other), "another seed, other noise"
    # per action: [tension, rest length] then the reward (the first observation has none)
    at = [0] + [2 + 3 * k for k in range(20)]
    tension_error = noisy[at] - truth[at]
    rms = float(np.sqrt(np.mean(tension_error**2)))
    assert 0.2 < rms < 1.0, f"sensed with 0.5 N of noise, rms {rms} N"
    # the rest length: an encoder of 1e-4 m counts
    at = [a + 1 for a in at]
    assert np.max(np.abs(noisy[at] - truth[at])) <= 0.5e-4 + 1e-12


def sixbar_episode(backend, seed, **kwargs):
    """Observations, rewards and infos of a SixbarRoll episode under seeded random actions (some
    outside [-1, 1], given as float32, as a list, as float64)."""
    env = gym.make("tensegrity/SixbarRoll-v0", backend=backend, max_episode_steps=8, **kwargs).unwrapped
    try:
        obs, info = env.reset(seed=seed)
        out, infos = [obs], [info]
        rng = np.random.default_rng(seed)
        for k in range(8):
            a = rng.uniform(-1.5, 1.5, size=24)
            a = [a.astype(np.float32), a.tolist(), a][k % 3]
            obs, reward, terminated, truncated, info = env.step(a)
            out += [obs, np.array([reward, terminated, truncated], dtype=np.float64)]
            infos.append(info)
        return np.concatenate(out), infos
    finally:
        env.close()


@pytest.mark.parametrize("kwargs", [{}, {"measured": True}, {"action": "rest_length", "normalize": False}],
                         ids=["state", "measured", "rest_length"])
def test_in_process_and_node_give_the_same_episodes_to_the_bit(kwargs):
    # the robot on the ground (contacts, 24 winches, sensors with noise when measured): the same
    # seed and actions through the extension and through a node over shared memory
    inproc, infos_a = sixbar_episode("inprocess", 9, **kwargs)
    node, infos_b = sixbar_episode("node", 9, **kwargs)
    assert np.array_equal(inproc, node)
    assert infos_a == infos_b


def test_in_process_callbacks_see_the_same_states_as_over_shared_memory():
    # a reward and a termination of the user's: the slow path, a `State` per step, in both
    def reward(state, action):
        return -abs(state.cable_tension[3] - 250.0) + 1e-3 * sum(state.body_position[0])

    def terminated(state):
        return state.time > 0.045

    rewards = {}
    for backend in BACKENDS:
        env = TensegrityEnv(actuators=["ring_winch"], reward=reward, terminated=terminated,
                            observation=("cable_tension", "body_orientation"), backend=backend)
        try:
            env.reset(seed=1)
            rewards[backend] = [env.step(np.array([0.3]))[1:3] for _ in range(6)]
        finally:
            env.close()
    assert rewards["inprocess"] == rewards["node"]
    assert [t for _, t in rewards["inprocess"]] == [False] * 4 + [True] * 2


def test_the_in_process_simulator_steps_and_records_like_a_node(tmp_path):
    bag = tmp_path / "run_bag"
    with InProcessSimulator("bundled:prism3", params={"record": str(bag)}) as sim:
        ring = sim.names["cable_names"].index("ring")
        state = sim.lockstep(100, [command("ring_winch", rate=-0.01)])
        assert state.step == 100 and abs(state.actuator_rate[0] + 0.01) < 1e-12
        assert state.cable_tension[ring] > sim.lockstep(0, reset=True).cable_tension[ring]
    # the bag it wrote replays bit for bit
    cli = Path(os.environ.get("TENSEGRITY_NODE", "tensegrity_node")).with_name("tensegrity")
    out = subprocess.run([str(cli), "replay", str(bag)], capture_output=True, text=True)
    assert out.returncode == 0 and "identical" in out.stdout, out.stdout + out.stderr


def test_a_huge_in_process_request_stops_at_ctrl_c():
    # 10^12 steps asked for by mistake: Ctrl-C stops it (KeyboardInterrupt) within a piece of
    # steps, and the simulator is usable at the step it reached
    # (Python keeps SIGINT ignored when it starts ignored, as under `nohup cmd &`: the child
    # installs the KeyboardInterrupt handler itself, so the test does not depend on its launcher)
    code = (
        "import signal\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "from tensegrity.testing.inprocess import InProcessSimulator\n"
        "sim = InProcessSimulator()\n"
        "print('ready', flush=True)\n"
        "try:\n"
        "    sim.lockstep(10**12)\n"
        "except KeyboardInterrupt:\n"
        "    s = sim.lockstep(1)\n"
        "    print('interrupted', s.step, min(s.cable_tension) > 0, flush=True)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # the installed package
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert p.stdout.readline().strip() == "ready"
        time.sleep(0.5)
        p.send_signal(signal.SIGINT)
        out, _ = p.communicate(timeout=20)
    finally:
        p.kill()
    words = out.split()
    assert p.returncode == 0 and words[0] == "interrupted" and int(words[1]) > 1 and words[2] == "True", out


def test_the_in_process_simulator_refuses_careless_input_and_goes_on(tmp_path):
    with pytest.raises(ValueError, match="nonexistent.toml"):
        InProcessSimulator(tmp_path / "nonexistent.toml")
    with pytest.raises(ValueError, match="physics_dt"):
        InProcessSimulator("bundled:prism3", params={"physics_dt": -1})
    with pytest.raises(ValueError, match="no bundled scene 'nothing_of_that_name'"):
        InProcessSimulator("bundled:nothing_of_that_name")
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "bad"\n[[bodies]]\nname = "b"\nkind = "bar"\nmass = -1.0\nends = [[0,0,0],[1,0,0]]\n')
    with pytest.raises(ValueError, match="bad.toml"):
        InProcessSimulator(bad)
    with InProcessSimulator("bundled:prism3") as sim:
        start = sim.lockstep(0)
        # a NaN, an out-of-range value, an unknown actuator: refused whole, no step taken
        for entry in (command(0, rate=float("nan")), command(0, rest_length=-5.0), command("no_such", rate=0.1)):
            with pytest.raises(LockstepRefused, match="command rejected"):
                sim.lockstep(5, [entry])
        assert sim.lockstep(0).step == start.step
        with pytest.raises(ValueError, match="seed"):
            sim.lockstep(1, seed=3)
        # and it goes on: the rejections counted as the node counts them
        after = sim.lockstep(3, [command("ring_winch", rate=-0.01)])
        assert after.step == 3 and after.commands_rejected == 3
        assert all(np.isfinite(after.cable_tension))
    env = TensegrityEnv(actuators=["ring_winch"], backend="inprocess")
    try:
        env.reset(seed=0)
        for careless in ([0.1, 0.2], [], "fast"):
            with pytest.raises((ValueError, TypeError)):
                env.step(careless)
        assert env.step(0.5)[0].shape == env.observation_space.shape
    finally:
        env.close()
    with pytest.raises(ValueError, match="target_tension"):
        TensegrityEnv(actuators=["ring_winch"], target_tension={"ring": 0.0}, backend="inprocess")
    with pytest.raises(ValueError, match="backend"):
        TensegrityEnv(backend="gpu")


def test_a_physics_failure_in_process_ends_the_episode_and_a_reset_recovers():
    # explicit Euler at 19 ms, just inside its stability limit for the rope as it starts (20 ms);
    # hauling the rope in stiffens it (EA / L0) until the step is past the limit and diverges:
    # the step is stopped and reported, the episode terminates, nothing non-finite comes out,
    # and a reset recovers
    scene = ROOT / "config" / "examples" / "sensors.toml"
    params = {"integrator": "symplectic-euler", "physics_dt": 0.019}
    env = TensegrityEnv(scene, backend="inprocess", params=params, max_episode_steps=1000)
    try:
        env.reset(seed=0)
        for _ in range(60):
            obs, reward, terminated, truncated, info = env.step(np.array([-1.0]))
            assert np.all(np.isfinite(obs))
            if terminated:
                break
        assert terminated and reward == -10.0 and "physics failure" in info["failure"], info
        obs, info = env.reset(seed=0)
        assert info["step"] == 0 and np.all(np.isfinite(obs))
        assert not env.step(np.array([0.0]))[2]
    finally:
        env.close()
    # past the limit from the start: refused when built, naming the limit
    with pytest.raises(ValueError, match="stability limit"):
        TensegrityEnv(scene, backend="inprocess", params={**params, "physics_dt": 0.05})


def test_a_parallel_vector_environment_in_process_survives_a_failure_and_resets_it():
    # two explicit-Euler loads as in the failure test above, one hauled in (it diverges), one held:
    # the failing one terminates with the failure, the other goes on, and the next step resets
    # the first (next-step autoreset: its reward 0)
    scene = ROOT / "config" / "examples" / "sensors.toml"
    vec = make_vector_env(2, scene=scene, backend="inprocess", max_episode_steps=1000,
                          params={"integrator": "symplectic-euler", "physics_dt": 0.019})
    try:
        assert all(env.backend == "inprocess" for env in vec.envs)
        vec.reset(seed=0)
        for _ in range(60):
            obs, reward, terminated, truncated, info = vec.step(np.array([[-1.0], [0.0]]))
            assert np.all(np.isfinite(obs))
            if terminated[0]:
                break
        assert terminated[0] and not terminated[1] and reward[0] == -10.0
        assert "physics failure" in info["failure"][0]
        obs, reward, terminated, truncated, info = vec.step(np.array([[0.0], [0.0]]))
        assert reward[0] == 0.0 and info["step"][0] == 0 and info["step"][1] > 0
        with pytest.raises(ValueError, match="finite"):
            vec.step(np.array([[np.nan], [0.0]]))
    finally:
        vec.close()


def test_rgb_array_frames_show_the_robot_and_record_a_video(tmp_path):
    # frames from the library's software renderer: the same seed and actions, the same pixels; a
    # rolling robot's frames change; Gymnasium's RecordVideo writes an episode (with moviepy)
    actions = np.random.default_rng(3).uniform(-1.0, 1.0, size=(6, 24))

    def frames():
        env = gym.make("tensegrity/SixbarRoll-v0", render_mode="rgb_array", max_episode_steps=6)
        try:
            env.reset(seed=5)
            out = [env.render()]
            for a in actions:
                env.step(a)
                out.append(env.render())
            return out
        finally:
            env.close()

    first, second = frames(), frames()
    assert all(f.shape == (240, 320, 3) and f.dtype == np.uint8 for f in first)
    assert all(np.array_equal(a, b) for a, b in zip(first, second)), "deterministic"
    assert not np.array_equal(first[0], first[-1]), "the robot moved"
    strut = np.all(np.abs(first[0].astype(int) - [70, 76, 92]) <= 6, axis=2)
    assert strut.sum() > 800 and strut[60:180, 80:240].sum() > strut.sum() / 2, "struts in the middle"
    env = TensegrityEnv(render_mode="rgb_array", render_size=(64, 48))
    assert env.render().shape == (48, 64, 3)
    assert TensegrityEnv().render() is None
    env.close()
    for bad in ({"render_mode": "window"}, {"render_size": (0, 10)}, {"render_mode": "rgb_array", "backend": "node"},
                {"render_mode": "human", "backend": "node"}, {"render_mode": "human", "viewer_port": -1},
                {"render_mode": "human", "viewer_port": 8080.5}):
        with pytest.raises(ValueError):
            TensegrityEnv(**bad)
    pytest.importorskip("moviepy")
    from gymnasium.wrappers import RecordVideo

    env = RecordVideo(gym.make("tensegrity/SixbarRoll-v0", render_mode="rgb_array", max_episode_steps=20),
                      str(tmp_path / "video"), episode_trigger=lambda e: True, disable_logger=True)
    env.reset(seed=1)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        done = terminated or truncated
    env.close()
    videos = list((tmp_path / "video").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000, videos


def test_human_mode_serves_the_episode_to_the_browser_viewer(monkeypatch):
    # render_mode="human": the viewer's page served from this process, following every step in
    # real time; its address printed (the browser is not opened under TENSEGRITY_NO_BROWSER)
    import json
    import time
    import urllib.request

    monkeypatch.setenv("TENSEGRITY_NO_BROWSER", "1")
    env = gym.make("tensegrity/SixbarRoll-v0", render_mode="human", max_episode_steps=5)
    try:
        start = time.monotonic()
        env.reset(seed=2)
        url = env.unwrapped.viewer_url
        assert url.startswith("http://127.0.0.1:")
        for _ in range(5):
            env.step(env.action_space.sample())
        elapsed = time.monotonic() - start
        simulated = env.unwrapped._last_info["time"]
        assert elapsed >= 0.9 * simulated, f"{elapsed} s of wall time for {simulated} s simulated: not paced"
        assert env.render() is None
        scene = json.load(urllib.request.urlopen(url + "scene.json", timeout=10))
        assert len(scene["struts"]) == 6 and len(scene["cables"]) == 24 and scene["source"] == "node"
        got = json.load(urllib.request.urlopen(url + "frames?from=0", timeout=10))
        assert got["status"]["state"] == "playing"
        assert len(got["frames"]) == 7, "the reset, five steps and the render"
        times = [f["t"] for f in got["frames"]]
        assert times == sorted(times) and times[-1] > times[0]
        assert "viewer.js" in urllib.request.urlopen(url, timeout=10).read().decode()
        # a second environment gets a port of its own
        other = TensegrityEnv(scene="bundled:prism3", render_mode="human")
        other.reset(seed=0)
        assert other.viewer_url != url
        other.close()
    finally:
        env.close()
    with pytest.raises(OSError):
        urllib.request.urlopen(url + "scene.json", timeout=2), "closed with the environment"
