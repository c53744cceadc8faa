"""The Gymnasium environments (`tensegrity_testing.envs`): both pass Gymnasium's own checker, the
same seed gives the same episodes to the bit (scene randomization included), a vector
environment's results equal the same environments stepped one by one, a recorded run of seeded
episodes replays bit for bit, and a short random search improves the return on the
tension-target task (the environment is learnable, not only valid).

Run: `pip install ./python[gym]` then `pytest python/tests`.
"""

import os
import subprocess
from pathlib import Path

import pytest

gym = pytest.importorskip("gymnasium")
np = pytest.importorskip("numpy")

from gymnasium.utils.env_checker import check_env  # noqa: E402

from tensegrity_testing.envs import TensegrityEnv, make_vector_env  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


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


def test_the_bundled_environment_passes_gymnasiums_checker():
    env = gym.make("tensegrity/Prism3Tension-v0")
    try:
        check_env(env.unwrapped, skip_render_check=True)
        obs, _ = env.reset(seed=0)
        assert env.observation_space.contains(obs)
        # a careless action is clipped to the space, a NaN refused
        obs, reward, *_ = env.step(np.array([7.0]))
        assert np.isfinite(reward) and env.observation_space.contains(obs)
        with pytest.raises(ValueError, match="finite"):
            env.step(np.array([np.nan]))
    finally:
        env.close()


def test_the_rolling_robot_environment_passes_gymnasiums_checker():
    env = gym.make("tensegrity/SixbarRoll-v0")
    try:
        check_env(env.unwrapped, skip_render_check=True)
        obs, _ = env.reset(seed=0)
        # hauling in every winch part way: the robot moves, the reward says how far toward the goal
        obs, reward, terminated, truncated, info = env.step(np.full(24, -0.5))
        assert np.all(np.isfinite(obs)) and np.isfinite(reward) and abs(reward) < 0.5
    finally:
        env.close()


def test_the_same_seed_gives_the_same_episodes_to_the_bit(tmp_path):
    scene = randomized_with_a_winch(tmp_path)
    actions = np.random.default_rng(7).uniform(-1.0, 1.0, size=(30, 1))
    a, b = TensegrityEnv(scene, action_period=5), TensegrityEnv(scene, action_period=5)
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


@pytest.mark.parametrize("vectorization", ["nodes", "async"])
def test_a_vector_environment_equals_its_environments_stepped_one_by_one(vectorization):
    # episodes of 6 actions: the 10 steps cross an autoreset (next-step mode: the step after the
    # end resets, reward 0)
    kwargs = {"actuators": ["ring_winch"], "target_tension": {"ring": 300.0}, "max_episode_steps": 6}
    actions = np.random.default_rng(3).uniform(-0.2, 0.2, size=(10, 2, 1))
    vec = make_vector_env(2, vectorization=vectorization, **kwargs)
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


def test_recorded_seeded_episodes_replay_bit_for_bit(tmp_path):
    scene = randomized_with_a_winch(tmp_path)
    bag = tmp_path / "episodes"
    env = TensegrityEnv(scene, action_period=5, params={"record": str(bag)})
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
