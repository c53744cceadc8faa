"""Gymnasium environments on the tensegrity simulator: `TensegrityEnv` runs one simulator in
lockstep and turns it into a `gymnasium.Env`. The simulator is in this process
(`backend="inprocess"`: the library's extension `tensegrity._native`, installed with the
package; no round trip between processes, the fastest) or a `tensegrity_node` process of its own, stepped over
shared memory (`backend="node"`: no DDS, so no network; isolated from this process's crashes).
`backend="auto"` (the default) is `"inprocess"`: the extension is always there. Both run the same node
core: the same seed and actions give the same episodes to the bit on either.

- observations: chosen arrays of the state after each action (tensions, lengths, rest lengths,
  rates, body positions and orientations), or what the scene's sensors report (`measured=True`:
  noisy, delayed, as declared in its `[sensors]`);
- actions: one number per actuator, a rest-length rate (m/s) or a rest-length target (m), within
  the actuator's declared limits (clipped there); with `normalize=True` (the default) each in
  [-1, 1], mapped linearly onto those limits;
- an action holds for `action_period` physics steps; an episode ends after `max_episode_steps`
  actions (truncated), or when `terminated(state)` says so or the physics fails (terminated);
- reward: `reward(state, action)`, by default the tension-target task: minus the mean relative
  error of the actuated cables' tensions from `target_tension` (N per cable name);
- `reset(seed=...)` is deterministic: the environment's generator, seeded once, draws each
  episode's seed, and the node resets with it, so the scene's randomization (`[randomize]`) and
  its sensors' noise are that episode's. The same seed gives the same episodes to the bit.

`make_vector_env(n, ...)` steps `n` of them as one `gymnasium.vector` environment, in parallel
from this process (`TensegrityVectorEnv`: the simulators in process, each on a core, or their
nodes), or each environment in a process of its own (`vectorization="async"`): every core works.

Registered ids: `tensegrity/Prism3Tension-v0` (the bundled prism3, its ring driven to 300 N by its
ring winch's rate), `tensegrity/SixbarRoll-v0` (`SixbarRollEnv`: the six-bar robot on the
ground rolled toward a goal by its 24 winches) and `tensegrity/SixbarRollGoal-v0`
(`SixbarRollGoalEnv`: the same robot rolled face by face to a goal in any direction, one cable
hauled per action: a task for learning).

The task itself (the action mapping, the observation layout, the default reward) is the
library's (`tensegrity::task` in Rust), read from the extension for both backends, so they
compute it with the same code. Needs `gymnasium` (`pip install './python[gym]'`).
"""

import math
import os
import sys
import time
import webbrowser
from functools import partial

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from . import _native
from .testing import inprocess
from .testing.node import TensegrityNode, command

#: The library's observation fields (`tensegrity._native.observation_fields()`): name -> what
#: it has one entry per (`cable`, `actuator`, `body`) and numbers per entry.
STATE_FIELDS = {f["name"]: (f["element"], f["width"]) for f in _native.observation_fields()}
#: What the sensors' channels fill instead, with `measured=True` (`State.measured` keys).
MEASURED_FIELDS = {f["name"]: f["sensor"] for f in _native.observation_fields() if f["sensor"]}
#: Reward of an action after which the physics failed (the episode terminates).
FAILURE_REWARD = -10.0


class TensegrityEnv(gym.Env):
    """One simulator as a Gymnasium environment (see the module docs).

    scene: a scene file, or `bundled:NAME` for a scene built into the node (default: the bundled
    prism3); action: "rate" or "rest_length"; normalize: actions in [-1, 1] (mapped onto the
    limits) instead of in SI units; actuators: the actuator names the action drives, in order
    (default: all); action_period:
    physics steps per action; max_episode_steps: actions per episode; observation: `State`
    fields, concatenated in order; measured: observe what the sensors report where the scene
    declares them; target_tension: {cable: N} of the default reward (default: 1.5 times each
    actuated cable's tension at the start, at least 1 N); reward(state, action) and
    terminated(state): your task instead; params: node parameters; node_timeout: seconds;
    backend: "inprocess", "node" or "auto" (module docs; `self.backend` says which it is);
    render_mode: "rgb_array" (in process) for `render()` frames of `render_size` (width, height)
    pixels; "human" (in process) to watch the episode in the browser viewer (`tensegrity
    view`'s page, served from this process on 127.0.0.1:`viewer_port`, 0 for a free port; its
    address is printed and opened in the browser unless TENSEGRITY_NO_BROWSER is set; steps are
    paced to real time); or None.
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 30}

    def __init__(self, scene=None, action="rate", normalize=True, actuators=None, action_period=10,
                 max_episode_steps=200, observation=("cable_tension", "actuator_rest_length"),
                 measured=False, target_tension=None, reward=None, terminated=None, params=None,
                 node_timeout=30.0, backend="auto", render_mode=None, render_size=(320, 240),
                 viewer_port=0):
        if render_mode not in (None, "rgb_array", "human"):
            raise ValueError(f"render_mode must be None, 'rgb_array' or 'human', got {render_mode!r}")
        if render_mode is not None and backend == "node":
            raise ValueError(f"render_mode={render_mode!r} draws the simulator in this process: use "
                             "backend='inprocess' (the default), or watch a node with `tensegrity view node`")
        if not (isinstance(viewer_port, int) and 0 <= viewer_port <= 65535):
            raise ValueError(f"viewer_port must be a port number, 0 to 65535, got {viewer_port!r}")
        self.viewer_port, self.viewer_url, self._pace = viewer_port, None, None
        width, height = (int(x) for x in render_size)
        if not (1 <= width <= 4096 and 1 <= height <= 4096):
            raise ValueError(f"render_size must be (width, height) in 1 to 4096 pixels, got {render_size}")
        self.render_mode, self.render_size = render_mode, (width, height)
        if action not in ("rate", "rest_length"):
            raise ValueError(f"action must be 'rate' or 'rest_length', got {action!r}")
        if int(action_period) < 1 or int(max_episode_steps) < 1:
            raise ValueError("action_period and max_episode_steps must be at least 1")
        unknown = [f for f in observation if f not in STATE_FIELDS]
        if unknown or not observation:
            raise ValueError(f"observation fields must be some of {sorted(STATE_FIELDS)}, got {list(observation)}")
        self.action_kind, self.action_period = action, int(action_period)
        self.max_episode_steps, self.fields, self.measured = int(max_episode_steps), tuple(observation), measured
        self._reward, self._terminated = reward, terminated
        if backend == "auto":
            backend = "inprocess"
        if backend == "inprocess":
            self.node = inprocess.InProcessSimulator(scene, params=params)
        elif backend == "node":
            self.node = TensegrityNode(scene, params=params, paused=True, transports=("shm",), timeout=node_timeout)
        else:
            raise ValueError(f"backend must be 'inprocess', 'node' or 'auto', got {backend!r}")
        self.backend = backend
        try:
            names = self.node.names
            all_actuators = names["actuator_names"]
            self.actuators = list(all_actuators if actuators is None else actuators)
            missing = [a for a in self.actuators if a not in all_actuators]
            if missing or not self.actuators:
                raise ValueError(f"actuators must be some of {all_actuators}, got {self.actuators}")
            index = [all_actuators.index(a) for a in self.actuators]
            if action == "rate":
                high = np.array([names["actuator_max_rate"][i] for i in index])
                low = -high
            else:
                low = np.array([names["actuator_min_rest_length"][i] for i in index])
                high = np.array([names["actuator_max_rest_length"][i] for i in index])
            # the limits in SI units; the space the agent sees
            self.limits = (low.astype(np.float64), high.astype(np.float64))
            if normalize:
                self.action_space = spaces.Box(low=-1.0, high=1.0, shape=low.shape, dtype=np.float64)
            else:
                self.action_space = spaces.Box(low=low, high=high, dtype=np.float64)
            self.normalize = normalize
            self._cables = [names["actuator_cable"][i] for i in index]
            start = self.node.lockstep(0)
            cable_names = names["cable_names"]
            if target_tension is None:
                target_tension = {cable_names[c]: max(1.5 * start.cable_tension[c], 1.0) for c in self._cables}
            self.target_tension = dict(target_tension)
            unknown = [c for c in self.target_tension if c not in cable_names]
            bad = [t for t in self.target_tension.values() if not (math.isfinite(t) and t > 0)]
            if unknown or bad or not self.target_tension:
                raise ValueError(f"target_tension must map cables of {cable_names} to tensions > 0 N, "
                                 f"got {self.target_tension}")
            targets = [(cable_names.index(c), float(t)) for c, t in self.target_tension.items()]
            # the task: the library's action mapping, observation layout and reward
            self._task = _native.Task(len(cable_names), len(all_actuators), len(names["body_names"]), index,
                                      action == "rate", self.limits[0].tolist(), self.limits[1].tolist(),
                                      normalize, list(self.fields), bool(measured), targets)
            # where each observed array sits: (field, elements, numbers per element)
            self._layout = self._task.layout()
            size = sum(n * width for _, n, width in self._layout)
            self.observation_space = spaces.Box(low=-np.inf, high=np.inf, shape=(size,), dtype=np.float64)
        except BaseException:
            self.node.stop()
            raise
        self._state, self._steps, self.episode_seed = start, 0, None
        # the hot path, as plain Python over the shared-memory sample: one command entry per
        # actuator, made once (by index)
        self._entries = [command(i, **{action: 0.0}) for i in index]
        # without callbacks or sensors a step reads the sample in place instead of a `State`;
        # in process, without callbacks, the whole step is one call into the extension
        self._fast = reward is None and terminated is None and not measured and backend == "node"
        self._native = None
        if backend == "inprocess" and reward is None and terminated is None:
            self._native = self.node.sim
            self._native.configure(self._task)
        self._observation = self.observe(start)
        self._last_info = self._info(start)
        # a video plays an action per frame, in simulated time
        period = self.action_period * names["physics_dt"]
        self.metadata = {**self.metadata, "render_fps": max(1, round(1.0 / period))}

    # ----- what the agent sees ---------------------------------------------------------------

    def observe(self, state):
        """The observation of `state` (a `State`): the chosen arrays, concatenated."""
        parts = []
        for f in self.fields:
            values = getattr(state, f)
            key = MEASURED_FIELDS.get(f)
            if self.measured and key in state.measured:
                values = state.measured[key]
            parts.append(np.asarray(values, dtype=np.float64).reshape(-1))
        return np.concatenate(parts)

    def _observe_sample(self, s):
        """`observe` of a `StateSample` `s` read in place (the same numbers as `State.of(s)`)."""
        values = []
        for field, n, width in self._layout:
            array = getattr(s, field)
            if width > 1:
                for i in range(n):
                    values.extend(array[i])
            else:
                values.extend(array[:n])
        return np.array(values, dtype=np.float64)

    def tension_reward(self, state, action=None):
        """The default reward: minus the mean of `|T - T*| / T*` over `target_tension`."""
        return self._tension_reward_of(state.cable_tension)

    def _tension_reward_of(self, tensions):
        """`tension_reward` of the cable tensions `tensions` (a `State`'s, or a sample's read in
        place): the library's (`tensegrity._native.Task.reward`)."""
        return self._task.reward(tensions)

    def _info(self, state):
        """`info` after `state` (a `State`, or a state sample read in place)."""
        return {"time": state.time, "step": state.step, "episode_seed": self.episode_seed}

    # ----- the Gymnasium interface -----------------------------------------------------------

    def reset(self, *, seed=None, options=None):
        """Resets the node, its episode drawn from this environment's generator (seeded by `seed`
        when given), and returns the first observation and `info` (time, step, episode_seed)."""
        super().reset(seed=seed)
        self.episode_seed = int(self.np_random.integers(0, 2**63))
        self._state = self.node.lockstep(0, reset=True, seed=self.episode_seed)
        self._steps = 0
        self._observation = self.observe(self._state)
        self._last_info = self._info(self._state)
        if self.render_mode == "human":
            self._pace = None
            self._show()
        return self._observation, dict(self._last_info)

    def command_values(self, action):
        """The rates (m/s) or rest lengths (m) `action` asks for, a list: clipped to the action
        space, mapped from [-1, 1] onto the limits when normalized (the library's mapping,
        `tensegrity._native.Task.values`). A NaN or infinite value, or the wrong number of them, is
        refused (`ValueError`)."""
        try:
            return self._task.values(action)
        except TypeError:  # not float64 numbers (ints, a list of numpy scalars): as floats
            return self._task.values(np.ravel(np.asarray(action, dtype=np.float64)))

    def step(self, action):
        """Applies `action` (clipped to the action space) for `action_period` physics steps."""
        result = self.step_end(self.step_begin(action), action)
        if self.render_mode == "human":
            self._show()
        return result

    def _show(self):
        """`render_mode="human"`: the current state to the browser viewer (started at the first
        call), then waits until as much wall time has passed since the reset as simulated time."""
        sim = self.node.sim
        if self.viewer_url is None:
            self.viewer_url = sim.start_viewer(self.viewer_port)
            print(f"tensegrity viewer at {self.viewer_url}", file=sys.stderr)
            if not os.environ.get("TENSEGRITY_NO_BROWSER"):
                webbrowser.open(self.viewer_url)
        else:  # starting it handed over the current state already
            sim.view_frame()
        t = float(self._last_info.get("time", 0.0))
        now = time.monotonic()
        if self._pace is None:
            self._pace = (now, t)
        wait = (t - self._pace[1]) - (now - self._pace[0])
        if wait > 0:
            time.sleep(wait)

    def step_begin(self, action):
        """`step`'s request, sent to the node without waiting for it (several environments then
        step their nodes in parallel: `TensegrityVectorEnv`); what it returns goes to `step_end`.
        """
        if self._native is not None:
            return self._act(action)
        key = self.action_kind
        for entry, x in zip(self._entries, self.command_values(action)):
            setattr(entry, key, x)
        try:
            if self._fast:
                return self.node.shm.lockstep_begin(self.action_period, self._entries)
            return self.node.lockstep_begin(self.action_period, self._entries)
        except Exception as e:  # the node could not be asked
            return e

    def _act(self, action):
        """`step_begin` in process: the whole step in one call (mapping, steps, observation,
        reward); a failed step is handed to `step_end`."""
        try:
            try:
                return self._native.act(action, self.action_period)
            except TypeError:  # not float64 numbers: as `command_values` reads them
                return self._native.act(np.ravel(np.asarray(action, dtype=np.float64)), self.action_period)
        except self.node.PhysicsFailure as e:
            return e

    def step_end(self, pending, action=None):
        """The result of the request `step_begin` sent: observation, reward, terminated,
        truncated, info."""
        self._steps += 1
        truncated = self._steps >= self.max_episode_steps
        try:
            if isinstance(pending, Exception):
                raise pending
            if self._native is not None:
                self._observation, reward, faulted, time, step = pending
                info = self._last_info = {"time": time, "step": step, "episode_seed": self.episode_seed}
                return self._observation, reward, faulted, truncated, info
            if self._fast:
                answer = self.node.shm.lockstep_end(pending, timeout=self.node.timeout)
            else:
                state = self.node.lockstep_end(pending)
        except Exception as e:  # the physics failed (the node is faulted until reset), or refused
            info = dict(self._last_info, failure=str(e))
            return self._observation, FAILURE_REWARD, True, truncated, info
        if self._fast:
            s = answer.state
            self._observation = self._observe_sample(s)
            reward = self._tension_reward_of(s.cable_tension)
            info = self._last_info = self._info(s)
            terminated = bool(s.faulted)
            del s, answer
            return self._observation, reward, terminated, truncated, info
        self._state = state
        self._observation = self.observe(state)
        reward = (self._reward or self.tension_reward)(state, action)
        terminated = bool(self._terminated(state)) if self._terminated else bool(state.faulted)
        if not math.isfinite(reward):
            raise ValueError(f"the reward is not finite: {reward}")
        self._last_info = self._info(state)
        return self._observation, float(reward), terminated, truncated, self._last_info

    def render(self):
        """With `render_mode="rgb_array"`: the current state as a `(height, width, 3)` uint8 array
        (`render_size`; the library's software renderer: struts grey, cables blue to red by
        tension, slack ones pale, contacts green, the ground's grid; the camera frames the
        structure). The same state gives the same pixels. With "human": the state to the browser
        viewer (done at every reset and step already), None. None without a render mode."""
        if self.render_mode is None:
            return None
        if self.render_mode == "human":
            self._show()
            return None
        return self.node.sim.render(*self.render_size)

    def close(self):
        """Stops the node."""
        if getattr(self, "node", None) is not None:
            self.node.stop()
            self.node = None


class SixbarRollEnv(TensegrityEnv):
    """The bundled six-bar robot on the ground (`bundled:sixbar_rover`): its 24 winches' rest-length
    targets as the action, every body's position and orientation and every cable's tension as
    the observation, 50 physics steps (50 ms) per action. Reward: how much closer the centre of
    its struts came to the goal (`goal`, m, in the floor's plane) during the action, m; the
    episode ends there (within `reach` m).
    """

    def __init__(self, goal=(2.0, 0.0), reach=0.1, **kwargs):
        kwargs.setdefault("scene", "bundled:sixbar_rover")
        kwargs.setdefault("action", "rest_length")
        kwargs.setdefault("action_period", 50)
        kwargs.setdefault("max_episode_steps", 400)
        kwargs.setdefault("observation", ("body_position", "body_orientation", "cable_tension"))
        kwargs.setdefault("params", {"start_from_equilibrium": True})
        self.goal, self.reach = np.asarray(goal, dtype=np.float64), float(reach)
        super().__init__(reward=self._progress, terminated=self._arrived, **kwargs)
        self._distance = self.distance(self._state)

    def distance(self, state):
        """How far the struts' centre is from the goal in the floor's plane, m."""
        centre = np.mean(np.asarray(state.body_position, dtype=np.float64)[:, :2], axis=0)
        return float(np.linalg.norm(centre - self.goal))

    def reset(self, *, seed=None, options=None):
        obs, info = super().reset(seed=seed, options=options)
        self._distance = self.distance(self._state)
        return obs, info

    def _progress(self, state, action):
        now = self.distance(state)
        progress, self._distance = self._distance - now, now
        return progress

    def _arrived(self, state):
        return state.faulted or self._distance <= self.reach


#: The six-bar rover's randomization and pose sensors for `SixbarRollGoalEnv(randomize=True)`
#: (scene-format tables): per reset, every cable's EA (x0.7 to 1.3) and damping (x0.5 to 2) and
#: every strut's mass (x0.8 to 1.2) drawn on its own, every rest length offset (sigma 5 mm);
#: positions measured to 1 cm and orientations to 0.02 rad (sigma).
ROVER_RANDOMIZATION = """
[randomize]
seed = 1
per = "reset"

[[randomize.parameters]]
parameter = "ea"
distribution = "uniform"
low = 0.7
high = 1.3

[[randomize.parameters]]
parameter = "damping"
distribution = "uniform"
low = 0.5
high = 2.0

[[randomize.parameters]]
parameter = "mass"
distribution = "uniform"
low = 0.8
high = 1.2

[[randomize.parameters]]
parameter = "rest_length"
distribution = "normal"
mean = 0.0
sigma = 0.005

[sensors.position]
sigma = 0.01

[sensors.orientation]
sigma = 0.02
"""


#: The rover's strut length, m (`tensegrity generate sixbar`).
STRUT_LENGTH = 1.0


def _rotate_z(q):
    """The z axes of the unit quaternions `q` `(n, 4)` `[x, y, z, w]`: `(n, 3)`."""
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=1)


class SixbarRollGoalEnv(gym.Env):
    """The six-bar rover rolled face by face to a goal `distance` m away in a direction drawn
    each episode (1.5 m: at least three rolls of about 0.44 m to come within `reach`, 0.3 m): a
    task designed for learning (what `benches/learn_roll.py` trains on).

    - action: which cable to haul (`Discrete(24)`, in the scene's cable order): its winch takes
      it in to `haul_fraction` of its rest length for `haul` s, then every winch lets out to its
      rest length for `release` s (one action: 1.5 s of simulated time by default). Hauling a
      cable between two of the three feet tips the robot over that edge onto the next face
      (about 0.44 m); the others barely move it.
    - observation (37 numbers): the 12 strut ends (`x0.a`, `x1.a`, ... `z1.a`, then the `b`
      ends), m, relative to the struts' centre, in a frame turned about the vertical so that the
      goal lies along +x; then the distance to the goal, m. From the state, or with `randomize`
      from the noisy pose sensors.
    - reward: progress toward the goal per action, dm. The episode ends within `reach` m of the
      goal (terminated, `info["reached"]`), when the physics fails (terminated, `info["failure"]`)
      or after `max_actions` actions (truncated).
    - `randomize`: the robot's parameters drawn anew at every reset and its pose measured with
      noise (`ROVER_RANDOMIZATION`), for training a policy that transfers. Such a robot starts
      from the scene's pose and settles for `settle` s before the episode begins (a drawn robot
      need not have an equilibrium with its feet held where the scene sets them: 2 of 60 draws
      here would slip), the nominal one from its equilibrium.
    - `info["time"]`: simulated time since the episode began, s.
    - `reset(seed=...)`: the goal's direction and the episode's robot come from the seed.

    `roller_action()` is the hand-written roller of `tests/kit.rs` on the current state (the
    cable between two feet whose roll points most toward the goal), a baseline for learned
    policies. `newton_tolerance` is the simulator's (1e-6 by default: the robot's speed setting,
    docs/benchmarks.md's Newton tolerance); `render_mode="rgb_array"` draws frames.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(self, distance=1.5, reach=0.3, max_actions=16, haul=1.0, release=0.5, haul_fraction=0.57,
                 randomize=False, settle=1.0, newton_tolerance=1e-6, render_mode=None, render_size=(480, 360)):
        import re
        import tempfile

        from .library import generate

        for name, value, low, high in (("distance", distance, 0.0, 100.0), ("reach", reach, 0.0, 100.0),
                                       ("haul", haul, 0.1, 60.0), ("release", release, 0.1, 60.0),
                                       ("haul_fraction", haul_fraction, 0.2, 1.0), ("settle", settle, 0.0, 60.0)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not low < value <= high:
                raise ValueError(f"{name} must be a number in ({low}, {high}], got {value!r}")
        if isinstance(max_actions, bool) or not isinstance(max_actions, int) or max_actions < 1:
            raise ValueError(f"max_actions must be a positive int, got {max_actions!r}")
        text = generate("sixbar", all_winches=True)
        self._routes = re.findall(r'route = \["([^"]+)", "([^"]+)"\]', text)
        self._scene_dir = None
        scene = "bundled:sixbar_rover"
        if randomize:
            self._scene_dir = tempfile.TemporaryDirectory(prefix="sixbar_roll_goal_")
            scene = os.path.join(self._scene_dir.name, "sixbar_rover_randomized.toml")
            with open(scene, "w") as f:
                f.write(text + ROVER_RANDOMIZATION)
        period = 100  # physics steps of 1 ms per inner action
        self.inner = TensegrityEnv(scene=scene, action="rest_length", normalize=False, action_period=period,
                                   max_episode_steps=2**62, observation=("body_position", "body_orientation"),
                                   measured=bool(randomize),
                                   params={"start_from_equilibrium": not randomize,
                                           "newton_tolerance": newton_tolerance},
                                   render_mode=render_mode, render_size=render_size)
        names = self.inner.node.names
        self._ends = [f"{b}.{e}" for e in "ab" for b in names["body_names"]]
        if len(self._routes) != len(self.inner.actuators) or any(
                a != f"w_{c}" for a, c in zip(self.inner.actuators, names["cable_names"])):
            raise RuntimeError("the generated rover does not match the bundled one")
        dt = names["physics_dt"]
        self._haul_periods = max(1, round(haul / (period * dt)))
        self._release_periods = max(1, round(release / (period * dt)))
        self._settle_periods = round(settle / (period * dt)) if randomize else 0
        self.action_seconds = (self._haul_periods + self._release_periods) * period * dt
        self.distance, self.reach, self.max_actions = float(distance), float(reach), max_actions
        self.haul_fraction = float(haul_fraction)
        self.randomize, self.render_mode = bool(randomize), render_mode
        self.action_space = spaces.Discrete(len(self._routes))
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(3 * len(self._ends) + 1,), dtype=np.float64)
        self.goal = np.zeros(2)
        self._obs, self._distance, self._actions, self._rest, self._start_time = None, 0.0, 0, None, 0.0

    def ends(self, obs=None):
        """The strut ends `(12, 3)` m (`a` ends, then `b`), from an inner observation (the current
        one by default): each strut's centre -+ half its length along its z axis."""
        obs = self._obs if obs is None else obs
        n = len(obs) // 7
        position, orientation = obs[: 3 * n].reshape(n, 3), obs[3 * n:].reshape(n, 4)
        orientation = orientation / np.linalg.norm(orientation, axis=1, keepdims=True)
        half = 0.5 * STRUT_LENGTH * _rotate_z(orientation)
        return np.concatenate([position - half, position + half])

    def _features(self):
        ends = self.ends()
        centre = ends.mean(axis=0)
        to_goal = self.goal - centre[:2]
        self._distance = float(np.linalg.norm(to_goal))
        c, s = to_goal / max(self._distance, 1e-12)
        rel = ends - centre
        turned = np.stack([c * rel[:, 0] + s * rel[:, 1], c * rel[:, 1] - s * rel[:, 0], rel[:, 2]], axis=1)
        return np.concatenate([turned.ravel(), [self._distance]])

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        angle = self.np_random.uniform(0.0, 2.0 * np.pi)
        self._obs, info = self.inner.reset(seed=int(self.np_random.integers(0, 2**62)))
        # the episode's rest lengths (a randomized robot's are offset): what the winches let out to
        rest = self.inner._state.cable_rest_length
        self._rest = np.array([rest[c] for c in self.inner._cables], dtype=np.float64)
        for _ in range(self._settle_periods):
            self._obs, _, terminated, _, info = self.inner.step(self._rest)
            if terminated:
                raise RuntimeError(f"the drawn robot did not settle: {info.get('failure')}")
        self._start_time = info["time"]
        start = self.ends().mean(axis=0)[:2]
        self.goal = start + self.distance * np.array([np.cos(angle), np.sin(angle)])
        self._actions = 0
        return self._features(), {"time": 0.0, "distance": self._distance, "goal": self.goal.copy()}

    def step(self, action):
        if self._rest is None:
            raise RuntimeError("reset the environment before stepping it")
        if not self.action_space.contains(action):
            raise ValueError(f"an action is a cable's index, 0 to {self.action_space.n - 1}, got {action!r}")
        hauled = self._rest.copy()
        hauled[int(action)] *= self.haul_fraction
        before, failure = self._distance, None
        for i in range(self._haul_periods + self._release_periods):
            obs, _, terminated, _, info = self.inner.step(hauled if i < self._haul_periods else self._rest)
            self._obs = obs
            if terminated:
                failure = info.get("failure", "the simulator faulted")
                break
        self._actions += 1
        features = self._features()
        reward = 10.0 * (before - self._distance)
        reached = self._distance <= self.reach
        info = {"time": info["time"] - self._start_time, "reached": reached, "distance": self._distance}
        if failure is not None:
            info["failure"] = failure
        return features, reward, reached or failure is not None, self._actions >= self.max_actions, info

    def roller_action(self):
        """The hand-written roller of `tests/kit.rs`: of the cables between two of the three
        lowest strut ends (the feet), the one whose roll points most toward the goal. The robot
        rolls along that edge toward the side the two struts lean to (the horizontal runs from
        each foot to its strut's centre, summed along the edge)."""
        ends = self.ends()
        n = len(ends) // 2
        feet = set(np.argsort(ends[:, 2])[:3].tolist())
        toward = self.goal - ends.mean(axis=0)[:2]
        index = {name: i for i, name in enumerate(self._ends)}
        best, best_along = 0, -np.inf
        for k, (a, b) in enumerate(self._routes):
            ia, ib = index[a], index[b]
            if ia not in feet or ib not in feet:
                continue
            centre_a, centre_b = (ends[ia % n] + ends[ia % n + n]) / 2, (ends[ib % n] + ends[ib % n + n]) / 2
            edge = (ends[ib] - ends[ia])[:2]
            lean = np.dot((centre_a - ends[ia])[:2] + (centre_b - ends[ib])[:2], edge)
            along = (1.0 if lean >= 0 else -1.0) * np.dot(edge, toward) / np.linalg.norm(edge)
            if along > best_along:
                best, best_along = k, along
        return best

    def render(self):
        """An `rgb_array` frame of the robot (`TensegrityEnv.render`), or None."""
        return self.inner.render()

    def close(self):
        if getattr(self, "inner", None) is not None:
            self.inner.close()
            self.inner = None
        if getattr(self, "_scene_dir", None) is not None:
            self._scene_dir.cleanup()
            self._scene_dir = None


class TensegrityVectorEnv(gym.vector.VectorEnv):
    """`n` `TensegrityEnv(**kwargs)` stepped from this process, in parallel on every core, with
    no pipes and no pickling (unlike `gymnasium.vector.AsyncVectorEnv`):

    - in process (`backend="inprocess"` or "auto"), one call
      steps every simulator, each on a core of its own while Python waits
      (`tensegrity._native.act_all`); with reward or termination callbacks they step one after
      another;
    - as nodes (`backend="node"`), each step sends every node its request
      (`TensegrityEnv.step_begin`) before it waits for any answer, so the nodes, each a process
      of its own, step in parallel while this process only copies numbers.

    An environment whose episode ended is reset at its next step (Gymnasium's next-step
    autoreset: that step's observation is the reset one, its reward 0).
    """

    metadata = {"render_modes": [], "autoreset_mode": gym.vector.AutoresetMode.NEXT_STEP}

    def __init__(self, n, **kwargs):
        if int(n) < 1:
            raise ValueError(f"a vector environment needs at least one environment, got {n}")
        self.envs = []
        try:
            for _ in range(int(n)):
                self.envs.append(TensegrityEnv(**kwargs))
        except BaseException:
            self.close()
            raise
        self.num_envs = len(self.envs)
        self.single_observation_space = self.envs[0].observation_space
        self.single_action_space = self.envs[0].action_space
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, self.num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, self.num_envs)
        self._ended = np.zeros(self.num_envs, dtype=bool)

    def reset(self, *, seed=None, options=None):
        """Resets every environment: `seed` an int (environment i gets `seed + i`), a list of
        seeds, or None."""
        if seed is None or isinstance(seed, int):
            seeds = [None if seed is None else seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"{len(seeds)} seeds for {self.num_envs} environments")
        observations, infos = [], {}
        for i, (env, s) in enumerate(zip(self.envs, seeds)):
            obs, info = env.reset(seed=s, options=options)
            observations.append(obs)
            infos = self._add_info(infos, info, i)
        self._ended[:] = False
        return np.stack(observations), infos

    def step(self, actions):
        """Steps every environment with its row of `actions`, the nodes in parallel."""
        actions = np.asarray(actions, dtype=np.float64).reshape(self.action_space.shape)
        live = [i for i in range(self.num_envs) if not self._ended[i]]
        pending = [None] * self.num_envs
        native = [self.envs[i]._native for i in live]
        periods = {self.envs[i].action_period for i in live}
        if live and all(n is not None for n in native) and len(periods) == 1:
            # every simulator in this process: one call steps them all, in parallel
            for i, result in zip(live, inprocess.act_all(native, [actions[i] for i in live], periods.pop())):
                pending[i] = result
        else:
            for i in live:
                pending[i] = self.envs[i].step_begin(actions[i])
        observations = []
        rewards = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        infos = {}
        for i, env in enumerate(self.envs):
            if self._ended[i]:
                obs, info = env.reset()
            else:
                obs, rewards[i], terminated[i], truncated[i], info = env.step_end(pending[i], actions[i])
            observations.append(obs)
            infos = self._add_info(infos, info, i)
        self._ended = terminated | truncated
        return np.stack(observations), rewards, terminated, truncated, infos

    def close_extras(self, **kwargs):
        """Stops every node."""
        for env in self.envs:
            env.close()


def make_vector_env(n, vectorization="parallel", **kwargs):
    """`n` `TensegrityEnv(**kwargs)` as one `gymnasium.vector` environment: `"parallel"` (the
    default; `"nodes"` is the same) steps them from this process in parallel
    (`TensegrityVectorEnv`: in process, or their nodes, as `backend` says), `"async"` runs each
    environment in a process of its own (`gymnasium.vector.AsyncVectorEnv`), `"sync"` one after
    another (`SyncVectorEnv`)."""
    if vectorization in ("parallel", "nodes"):
        return TensegrityVectorEnv(n, **kwargs)
    fns = [partial(TensegrityEnv, **kwargs) for _ in range(n)]
    if vectorization == "async":
        return gym.vector.AsyncVectorEnv(fns)
    if vectorization == "sync":
        return gym.vector.SyncVectorEnv(fns)
    raise ValueError(f"vectorization must be 'parallel', 'async' or 'sync', got {vectorization!r}")


gym.register(
    id="tensegrity/Prism3Tension-v0",
    entry_point="tensegrity.envs:TensegrityEnv",
    kwargs={"action": "rate", "actuators": ["ring_winch"], "target_tension": {"ring": 300.0}},
)
gym.register(id="tensegrity/SixbarRoll-v0", entry_point="tensegrity.envs:SixbarRollEnv")
gym.register(id="tensegrity/SixbarRollGoal-v0", entry_point="tensegrity.envs:SixbarRollGoalEnv")
