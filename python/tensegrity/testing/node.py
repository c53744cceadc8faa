"""`tensegrity_node` as a subprocess for one test: started on a leased DDS domain with its own
shared-memory prefix, ready when its transports are discoverable, stopped (and waited for) at the
end, whatever the test did.

    from tensegrity.testing import TensegrityNode
    with TensegrityNode() as sim:               # the bundled prism3, paused: the test owns time
        state = sim.lockstep(10)                 # 10 steps (shared memory), the state after them
        sim.send(0, rate=-0.01)                  # a command over DDS, applied at the next step

The node's exit status tells why it stopped (`EXIT_STATUS`); `stop()` returns it and the fixture
fails the test's teardown when it is not 0.
"""

import ctypes
import itertools
import os
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import leases, msgs

# tensegrity_node's exit statuses (tensegrity_node --help)
EXIT_STATUS = {
    0: "stopped by SIGINT, SIGTERM or SetSimulationState(QUITTING)",
    2: "bad arguments or parameters",
    3: "the scene cannot be read or is invalid",
    4: "a transport (DDS, shared memory, the bag recorder) cannot start",
    5: "a physics failure (the simulation cannot start, or it stopped while faulted)",
}

_sequence = itertools.count()
PR_SET_PDEATHSIG = 1


class NodeFailed(RuntimeError):
    """The node exited (or never became ready): `status` (see EXIT_STATUS) and its stderr."""

    def __init__(self, status, stderr, what="the node exited"):
        meaning = EXIT_STATUS.get(status, "killed by a signal" if status is not None and status < 0 else "")
        super().__init__(f"{what} with status {status} ({meaning}):\n{stderr}")
        self.status = status
        self.stderr = stderr


def find_executable():
    """`tensegrity_node`: $TENSEGRITY_NODE, else on PATH, else a cargo build (target/release, then
    target/debug) of the checkout this package runs from or of the working directory or one of
    its parents (pytest run from a checkout with the package installed)."""
    named = os.environ.get("TENSEGRITY_NODE")
    if named:
        return named
    found = shutil.which("tensegrity_node")
    if found:
        return found
    cwd = Path.cwd().resolve()
    looked = []
    for root in (Path(__file__).resolve().parents[2], cwd, *cwd.parents):
        for profile in ("release", "debug"):
            candidate = root / "target" / profile / "tensegrity_node"
            if candidate.exists():
                return str(candidate)
            looked.append(str(candidate))
    raise FileNotFoundError(
        "tensegrity_node not found: TENSEGRITY_NODE is not set, it is not on PATH, and none of "
        + ", ".join(dict.fromkeys(looked))
        + " exists. Set TENSEGRITY_NODE to the binary, or run `cargo install --path .` in the "
        "simulator's checkout (puts it in ~/.cargo/bin), or `cargo build --release` there"
    )


def _die_with_parent():
    # the node gets SIGTERM if the test process dies without stopping it (Linux)
    try:
        ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (AttributeError, OSError):
        pass


def _param_text(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return ",".join(str(v) for v in value)
    return str(value)


@dataclass
class Contact:
    """One contact after a step: a sphere's point and its ground (a strut pair: its two bars),
    pressed in or not, gap (m, negative: pressed in), normal force (N), contact point (m), unit
    normal, friction force on the body (N) and slip speed (m/s)."""

    point: str
    other: str
    in_contact: bool
    gap: float
    normal_force: float
    position: tuple
    normal: tuple
    friction: tuple
    slip_speed: float


@dataclass
class State:
    """The state after a step, copied out of shared memory (SI units; arrays in the order of the
    structure's names)."""

    time: float
    step: int
    faulted: bool
    body_position: list = field(default_factory=list)
    body_orientation: list = field(default_factory=list)
    cable_tension: list = field(default_factory=list)
    cable_length: list = field(default_factory=list)
    cable_rest_length: list = field(default_factory=list)
    cable_slack: list = field(default_factory=list)
    actuator_rest_length: list = field(default_factory=list)
    actuator_rate: list = field(default_factory=list)
    pulley_slip_speed: list = field(default_factory=list)
    pulley_tension_ratio: list = field(default_factory=list)
    pulley_sticks: list = field(default_factory=list)
    commands_rejected: int = 0
    contacts: list = field(default_factory=list)
    # what the scene's sensors report (lockstep, scenes with [sensors]): channel name to values,
    # in the arrays' layout ("tension", "length", "rest_length", "position", "orientation")
    measured: dict = field(default_factory=dict)
    # per reported value, True when it is held because its last update was lost (a dropout): the
    # same channel names and layout as `measured` (an orientation has one flag per body)
    measured_lost: dict = field(default_factory=dict)

    @classmethod
    def of(cls, s):
        b, c, a = s.body_count, s.cable_count, s.actuator_count
        return cls(
            time=s.time,
            step=s.step,
            faulted=bool(s.faulted),
            body_position=[tuple(s.body_position[i]) for i in range(b)],
            body_orientation=[tuple(s.body_orientation[i]) for i in range(b)],
            cable_tension=list(s.cable_tension[:c]),
            cable_length=list(s.cable_length[:c]),
            cable_rest_length=list(s.cable_rest_length[:c]),
            cable_slack=[bool(x) for x in s.cable_slack[:c]],
            actuator_rest_length=list(s.actuator_rest_length[:a]),
            actuator_rate=list(s.actuator_rate[:a]),
            pulley_slip_speed=list(s.pulley_slip_speed[: s.pulley_count]),
            pulley_tension_ratio=list(s.pulley_tension_ratio[: s.pulley_count]),
            pulley_sticks=[bool(x) for x in s.pulley_sticks[: s.pulley_count]],
            commands_rejected=s.commands_rejected,
        )


def state_of(s, names, contacts=None, measured=None):
    """The `State` of a `StateSample` `s`, with the contacts of a `ContactsSample` and what the
    sensors report from a `MeasuredSample` where they are of the same step (`names`: the
    structure's names)."""
    state = State.of(s)
    c = contacts
    if c is not None and c.step == state.step:
        state.contacts = [
            Contact(point, other, bool(c.in_contact[i]), c.gap[i], c.normal_force[i],
                    tuple(c.position[i]), tuple(c.normal[i]), tuple(c.friction[i]), c.slip_speed[i])
            for i, (point, other) in enumerate(names["contacts"])
        ]
    if measured is not None and measured.step == state.step:
        state.measured = measured_of(measured)
        state.measured_lost = measured_lost_of(measured)
    return state


def measured_of(m):
    """The declared channels of a `MeasuredSample` `m`, as lists in the state's layout."""
    from . import shm

    b, c, a = m.body_count, m.cable_count, m.actuator_count
    out = {}
    if m.channels & shm.MEASURED_TENSION:
        out["tension"] = list(m.cable_tension[:c])
    if m.channels & shm.MEASURED_LENGTH:
        out["length"] = list(m.cable_length[:c])
    if m.channels & shm.MEASURED_REST_LENGTH:
        out["rest_length"] = list(m.actuator_rest_length[:a])
    if m.channels & shm.MEASURED_POSITION:
        out["position"] = [tuple(m.body_position[i]) for i in range(b)]
    if m.channels & shm.MEASURED_ORIENTATION:
        out["orientation"] = [tuple(m.body_orientation[i]) for i in range(b)]
    if m.channels & (shm.MEASURED_GYRO | shm.MEASURED_ACCELEROMETER):
        # the IMU's truth travels with what it reports (the state has no accelerations)
        out["true_gyro"] = [tuple(m.true_angular_velocity[i]) for i in range(b)]
        out["true_accelerometer"] = [tuple(m.true_specific_force[i]) for i in range(b)]
    if m.channels & shm.MEASURED_GYRO:
        out["gyro"] = [tuple(m.body_angular_velocity[i]) for i in range(b)]
    if m.channels & shm.MEASURED_ACCELEROMETER:
        out["accelerometer"] = [tuple(m.body_specific_force[i]) for i in range(b)]
    return out


def measured_lost_of(m):
    """The lost flags of a `MeasuredSample` `m`'s declared channels, as `measured_of` lays out
    the values: True where a value is held because its last update was lost."""
    from . import shm

    b, c, a = m.body_count, m.cable_count, m.actuator_count
    flags = lambda row: tuple(bool(x) for x in row)  # noqa: E731
    out = {}
    if m.channels & shm.MEASURED_TENSION:
        out["tension"] = [bool(x) for x in m.cable_tension_lost[:c]]
    if m.channels & shm.MEASURED_LENGTH:
        out["length"] = [bool(x) for x in m.cable_length_lost[:c]]
    if m.channels & shm.MEASURED_REST_LENGTH:
        out["rest_length"] = [bool(x) for x in m.actuator_rest_length_lost[:a]]
    if m.channels & shm.MEASURED_POSITION:
        out["position"] = [flags(m.body_position_lost[i]) for i in range(b)]
    if m.channels & shm.MEASURED_ORIENTATION:
        out["orientation"] = [bool(x) for x in m.body_orientation_lost[:b]]
    if m.channels & shm.MEASURED_GYRO:
        out["gyro"] = [flags(m.body_angular_velocity_lost[i]) for i in range(b)]
    if m.channels & shm.MEASURED_ACCELEROMETER:
        out["accelerometer"] = [flags(m.body_specific_force_lost[i]) for i in range(b)]
    return out


class TensegrityNode:
    """A running `tensegrity_node` (see the module docs).

    scene: a scene file (default: the bundled prism3); params: node parameters ({name: value},
    as `-p name:=value`); paused: start paused (lockstep) or playing in real time; transports:
    "dds", "shm" or both; timeout: seconds to wait for readiness and for each answer.
    """

    def __init__(self, scene=None, params=None, paused=True, transports=("dds", "shm"), executable=None,
                 timeout=30.0):
        self.timeout = timeout
        self.transports = tuple(transports)
        self.process = None
        self._participant = None
        self._writers = {}
        self._topics = {}
        self._waitsets = {}
        self.shm = None
        self.lease = None
        self.executable = executable or find_executable()
        self.lease = leases.DomainLease() if "dds" in self.transports else None
        self.domain = self.lease.id if self.lease else None
        # the ready file and the node's stderr; removed by stop(), which keeps the text
        self._scratch = scratch = Path(tempfile.mkdtemp(prefix="tensegrity-node-"))
        self._stderr_text = None
        self.ready_file = scratch / "ready"
        self.log_path = scratch / "stderr.log"
        args = [self.executable, "--ready-file", str(self.ready_file)]
        if scene is not None:
            args.append(str(scene))
        args += ["--ros-args", "-p", f"transports:={','.join(self.transports)}",
                 "-p", f"start_paused:={_param_text(paused)}"]
        if "shm" in self.transports and not (params and "shm_prefix" in params):
            args += ["-p", f"shm_prefix:=tensegrity_sim_py{os.getpid()}_{next(_sequence)}"]
        for name, value in (params or {}).items():
            args += ["-p", f"{name}:={_param_text(value)}"]
        env = dict(os.environ)
        if self.domain is not None:
            env["ROS_DOMAIN_ID"] = str(self.domain)
        try:
            self._log = open(self.log_path, "w+")
            self.process = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                            stderr=self._log, env=env, preexec_fn=_die_with_parent)
            self.pid = self.process.pid
            self.info = self._wait_ready()
            self.namespace = self.info["private_namespace"]
            self.shm_prefix = self.info["shm_prefix"] if "shm" in self.transports else None
            self._wait_discoverable()
        except BaseException:
            self.stop()
            raise

    # ----- start-up ------------------------------------------------------------------------

    def stderr(self):
        """Everything the node wrote to stderr so far."""
        if self._stderr_text is not None:
            return self._stderr_text
        try:
            return self.log_path.read_text()
        except OSError:
            return ""

    def _wait_ready(self):
        deadline = time.monotonic() + self.timeout
        while not self.ready_file.exists():
            status = self.process.poll()
            if status is not None:
                raise NodeFailed(status, self.stderr(), f"{self.executable} exited before it was ready")
            if time.monotonic() > deadline:
                raise TimeoutError(f"tensegrity_node not ready within {self.timeout} s:\n{self.stderr()}")
            time.sleep(0.01)
        lines = self.ready_file.read_text().splitlines()
        return dict(line.split("=", 1) for line in lines if "=" in line)

    def _wait_discoverable(self):
        if self.domain is not None:
            structure = self.reader("~/structure")
            if self.next(structure) is None:
                raise TimeoutError(f"no ~/structure on DDS domain {self.domain} within {self.timeout} s")
        if self.shm_prefix is not None:
            from .shm import TensegrityClient

            self.shm = TensegrityClient(self.shm_prefix, timeout=self.timeout)
            self.names = self.shm.structure(self.timeout)

    # ----- DDS -----------------------------------------------------------------------------

    @property
    def participant(self):
        """A Cyclone DDS participant on the node's domain (created on first use)."""
        if self.domain is None:
            raise RuntimeError("this node does not serve DDS (transports)")
        if self._participant is None:
            from cyclonedds.domain import DomainParticipant

            self._participant = DomainParticipant(self.domain)
        return self._participant

    def dds_topic_name(self, topic):
        """The DDS name of a ROS topic (`~/x` is the node's private namespace): `rt/...`."""
        full = self.namespace + topic[1:] if topic.startswith("~/") else topic
        return "rt" + full

    def _qos(self, topic, depth):
        from cyclonedds.core import Policy, Qos
        from cyclonedds.util import duration

        _, node_depth, transient = msgs.TOPICS[topic]
        policies = [Policy.Reliability.Reliable(duration(seconds=1)),
                    Policy.History.KeepLast(depth or max(node_depth, 16))]
        if transient:
            policies.append(Policy.Durability.TransientLocal)
        return Qos(*policies)

    def _topic(self, topic):
        """The DDS topic of `topic` on this participant (made once, shared by its readers and
        writers)."""
        from cyclonedds.topic import Topic

        if topic not in msgs.TOPICS:
            raise KeyError(f"unknown topic {topic!r}; the node's topics: {sorted(msgs.TOPICS)}")
        if topic not in self._topics:
            self._topics[topic] = Topic(self.participant, self.dds_topic_name(topic), msgs.TOPICS[topic][0])
        return self._topics[topic]

    def reader(self, topic, depth=None):
        """A reliable reader of one of the node's topics (`msgs.TOPICS`), typed from msg/."""
        from cyclonedds.sub import DataReader

        return DataReader(self.participant, self._topic(topic), qos=self._qos(topic, depth))

    def writer(self, topic="~/actuator_commands", depth=None):
        """A reliable writer of one of the node's input topics."""
        from cyclonedds.pub import DataWriter

        return DataWriter(self.participant, self._topic(topic), qos=self._qos(topic, depth))

    def next(self, reader, timeout=None):
        """The next sample `reader` receives (or has), or None after `timeout` seconds. Blocks on
        a Cyclone DDS wait set, so a sample is returned as soon as it arrives."""
        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
        from cyclonedds.util import duration

        waitset = self._waitsets.get(id(reader))
        if waitset is None:
            waitset = WaitSet(self.participant)
            waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
            # keyed by the reader's id, so the reader is kept with it
            self._waitsets[id(reader)] = (waitset, reader)
        else:
            waitset = waitset[0]
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            got = reader.take(N=1)
            if got:
                return got[0]
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            waitset.wait(duration(microseconds=max(1, int(left * 1e6))))

    def send(self, actuator, rest_length=None, rate=None, tension=None):
        """One command over DDS: a rest length and/or rate on `~/actuator_commands`, or a tension
        (N, a winch actuator's motor) on `~/tension_commands`; actuator by name or index."""
        if isinstance(actuator, int):
            actuator = self.names["actuator_names"][actuator]
        if tension is not None:
            if rest_length is not None or rate is not None:
                raise ValueError("a tension command carries no rest length or rate")
            w = self._writers.get("tension")
            if w is None:
                w = self._writers["tension"] = self.writer("~/tension_commands")
            w.write(msgs.TensionCommand(name=[actuator], tension=[tension]))
            return
        w = self._writers.get("cmd")
        if w is None:
            w = self._writers["cmd"] = self.writer()
        w.write(msgs.ActuatorCommand(name=[actuator],
                                     rest_length=[] if rest_length is None else [rest_length],
                                     rate=[] if rate is None else [rate]))

    # ----- lockstep (shared memory) --------------------------------------------------------

    def cable_index(self, name):
        """Index of cable `name` in the state's arrays."""
        return self.names["cable_names"].index(name)

    def lockstep(self, steps, commands=(), reset=False, seed=None):
        """Applies `commands` (`command(...)` entries) at the next boundary, takes `steps` steps
        (the node paused) and returns the `State` after them. With `reset`, the node resets
        first, its episode drawn from `seed` when given (`TensegrityClient.lockstep`)."""
        return self.lockstep_end(self.lockstep_begin(steps, commands, reset, seed))

    def lockstep_begin(self, steps, commands=(), reset=False, seed=None):
        """`lockstep`'s request, sent without waiting (`TensegrityClient.lockstep_begin`); its
        `State` comes from `lockstep_end`."""
        if self.shm is None:
            raise RuntimeError("lockstep needs the shared-memory transport (transports)")
        return self.shm.lockstep_begin(steps, list(commands), reset, seed)

    def lockstep_end(self, pending):
        """The `State` after the request `lockstep_begin` sent."""
        answer = self.shm.lockstep_end(pending, timeout=self.timeout)
        return state_of(answer.state, self.names, self.shm.latest_contacts(), self.shm.latest_measured())

    # ----- the end -------------------------------------------------------------------------

    def alive(self):
        """True while the process runs."""
        return self.process is not None and self.process.poll() is None

    def stop(self, timeout=10.0):
        """SIGINT, wait (SIGKILL after `timeout` s), release the domain; returns the exit status."""
        self.shm = None
        self._writers.clear()
        self._topics.clear()
        self._participant = None
        status = None
        if self.process is not None:
            if self.process.poll() is None:
                self.process.send_signal(signal.SIGINT)
                try:
                    self.process.wait(timeout)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait()
            status = self.process.returncode
            self._log.close()
        if self._stderr_text is None:
            self._stderr_text = self.stderr()
            shutil.rmtree(self._scratch, ignore_errors=True)
        self._waitsets.clear()
        if self.lease is not None:
            self.lease.release()
        return status

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
        return False


def command(actuator, rest_length=None, rate=None, tension=None):
    """A lockstep command entry: actuator by name or index, rest length (m) and/or rate (m/s),
    or a tension (N) alone for a winch actuator's motor."""
    from .shm import entry

    return entry(actuator, rest_length=rest_length, rate=rate, tension=tension)
