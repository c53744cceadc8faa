"""Drive the tensegrity simulator from Python over shared memory (iceoryx2, zero copy).

A library and a command-line self-test. Needs the PyPI package `iceoryx2==0.10.0` (the version
the node is built with: both sides must speak the same protocol).

Library use (a node running with `-p transports:=shm` or the default `dds,shm`, paused for
lockstep: `-p start_paused:=true`):

    from tensegrity.testing.shm import TensegrityClient, entry
    sim = TensegrityClient("tensegrity_sim")          # <namespace>/<node name>, no leading slash
    names = sim.structure()                            # scene, body/cable/actuator names
    answer = sim.lockstep(1, [entry("ring_winch", rest_length=4.9)])
    print(answer.state.time, answer.state.cable_tension[3])
    sim.send_command([entry(0, rate=-0.1)])            # while playing: applied at the next step
    s = sim.next_state(timeout=1.0)                    # a copy of the newest-but-unread sample

Command line (`python -m tensegrity.testing.shm`, or `tests/interop/shm_client.py`):

    shm_client.py [--prefix tensegrity_sim] [--check TARGET] [--bench N] [--spin-us 200]

`--check TARGET` runs the self-test the Rust test suite calls (node paused, publishing every
step): it reads the structure, sends a NaN command (must be rejected), steps by lockstep, drives
the first actuator to TARGET and checks the state; prints `OK ...` and exits 0, else exits 1.
`--bench N` times N one-step lockstep round trips and prints their median, p99 and rate.

The ctypes structures mirror the `#[repr(C)]` payloads of `src/io/shm/payload.rs` field by field, with
the same capacities and type names (iceoryx2 refuses to connect when name, size or alignment
differ, so a mismatch fails loudly at connect).
"""

import argparse
import ctypes
import math
import os
import statistics
import sys
import time

import iceoryx2 as iox2

MAX_BODIES = 256
MAX_CABLES = 1024
MAX_ACTUATORS = 256
MAX_CONTACTS = 512
MAX_PULLEYS = 1024
NAME_BYTES = 64
MESSAGE_BYTES = 256

EVENT_STATE = 1
EVENT_RESPONSE = 2
EVENT_COMMAND = 1
EVENT_LOCKSTEP = 2
EVENT_HELLO = 3

BY_NAME = 0xFFFFFFFF
FIELD_REST_LENGTH = 1
FIELD_RATE = 2
FIELD_TENSION = 4
LOCKSTEP_RESET = 1
LOCKSTEP_SEEDED = 2

RESULT_OK = 1

f64 = ctypes.c_double
u64 = ctypes.c_uint64
u32 = ctypes.c_uint32
u8 = ctypes.c_uint8
Name = u8 * NAME_BYTES


class StateSample(ctypes.Structure):
    """`TensegrityState`: the state after a step (see `StateSample` in src/io/shm/payload.rs)."""

    _fields_ = [
        ("time", f64),
        ("step", u64),
        ("published_ns", u64),
        ("commands_applied_ns", u64),
        ("commands_received", u64),
        ("commands_accepted", u64),
        ("commands_rejected", u64),
        ("overruns", u64),
        ("body_count", u32),
        ("cable_count", u32),
        ("actuator_count", u32),
        ("simulation_state", u8),
        ("faulted", u8),
        ("reserved", u8 * 2),
        ("body_position", (f64 * 3) * MAX_BODIES),
        ("body_orientation", (f64 * 4) * MAX_BODIES),
        ("cable_tension", f64 * MAX_CABLES),
        ("cable_length", f64 * MAX_CABLES),
        ("cable_rest_length", f64 * MAX_CABLES),
        ("actuator_rest_length", f64 * MAX_ACTUATORS),
        ("actuator_rate", f64 * MAX_ACTUATORS),
        ("cable_slack", u8 * MAX_CABLES),
        ("pulley_count", u32),
        ("pulley_reserved", u32),
        ("pulley_slip_speed", f64 * MAX_PULLEYS),
        ("pulley_tension_ratio", f64 * MAX_PULLEYS),
        ("pulley_sticks", u8 * MAX_PULLEYS),
    ]

    @staticmethod
    def type_name() -> str:
        return "TensegrityState"


class StructureSample(ctypes.Structure):
    """`TensegrityStructure`: names and array order, published once for late joiners."""

    _fields_ = [
        ("physics_dt", f64),
        ("body_count", u32),
        ("cable_count", u32),
        ("actuator_count", u32),
        ("contact_count", u32),
        ("scene_name", Name),
        ("frame_id", Name),
        ("body_names", Name * MAX_BODIES),
        ("cable_names", Name * MAX_CABLES),
        ("actuator_names", Name * MAX_ACTUATORS),
        ("actuator_cable", u32 * MAX_ACTUATORS),
        ("actuator_min_rest_length", f64 * MAX_ACTUATORS),
        ("actuator_max_rest_length", f64 * MAX_ACTUATORS),
        ("actuator_max_rate", f64 * MAX_ACTUATORS),
        ("contact_point", Name * MAX_CONTACTS),
        ("contact_with", Name * MAX_CONTACTS),
    ]

    @staticmethod
    def type_name() -> str:
        return "TensegrityStructure"


class ContactsSample(ctypes.Structure):
    """`TensegrityContacts`: every contact after a step (scenes with contacts only)."""

    _fields_ = [
        ("time", f64),
        ("step", u64),
        ("contact_count", u32),
        ("reserved", u32),
        ("gap", f64 * MAX_CONTACTS),
        ("normal_force", f64 * MAX_CONTACTS),
        ("slip_speed", f64 * MAX_CONTACTS),
        ("position", (f64 * 3) * MAX_CONTACTS),
        ("normal", (f64 * 3) * MAX_CONTACTS),
        ("friction", (f64 * 3) * MAX_CONTACTS),
        ("in_contact", u8 * MAX_CONTACTS),
    ]

    @staticmethod
    def type_name() -> str:
        return "TensegrityContacts"


class MeasuredSample(ctypes.Structure):
    """`TensegrityMeasured`: what the scene's sensors report after a step (scenes with [sensors]
    only); `channels` has a bit per declared channel (MEASURED_*), the state keeps the truth (the
    IMU's truth, which needs accelerations the state lacks, is here: true_*)."""

    _fields_ = [
        ("time", f64),
        ("step", u64),
        ("channels", u32),
        ("body_count", u32),
        ("cable_count", u32),
        ("actuator_count", u32),
        ("body_position", (f64 * 3) * MAX_BODIES),
        ("body_orientation", (f64 * 4) * MAX_BODIES),
        ("cable_tension", f64 * MAX_CABLES),
        ("cable_length", f64 * MAX_CABLES),
        ("actuator_rest_length", f64 * MAX_ACTUATORS),
        ("body_angular_velocity", (f64 * 3) * MAX_BODIES),
        ("body_specific_force", (f64 * 3) * MAX_BODIES),
        ("true_angular_velocity", (f64 * 3) * MAX_BODIES),
        ("true_specific_force", (f64 * 3) * MAX_BODIES),
        # per value, 1 when it is held because its last update was lost (a dropout)
        ("body_position_lost", (u8 * 3) * MAX_BODIES),
        ("body_orientation_lost", u8 * MAX_BODIES),
        ("cable_tension_lost", u8 * MAX_CABLES),
        ("cable_length_lost", u8 * MAX_CABLES),
        ("actuator_rest_length_lost", u8 * MAX_ACTUATORS),
        ("body_angular_velocity_lost", (u8 * 3) * MAX_BODIES),
        ("body_specific_force_lost", (u8 * 3) * MAX_BODIES),
    ]

    @staticmethod
    def type_name() -> str:
        return "TensegrityMeasured"


MEASURED_TENSION = 1
MEASURED_LENGTH = 2
MEASURED_REST_LENGTH = 4
MEASURED_POSITION = 8
MEASURED_ORIENTATION = 16
MEASURED_GYRO = 32
MEASURED_ACCELEROMETER = 64


class CommandEntry(ctypes.Structure):
    """`TensegrityCommandEntry`: one actuator's target rest length and/or rate, or a tension."""

    _fields_ = [
        ("actuator", u32),
        ("fields", u32),
        ("rest_length", f64),
        ("rate", f64),
        ("tension", f64),
        ("name", Name),
    ]

    @staticmethod
    def type_name() -> str:
        return "TensegrityCommandEntry"


class CommandSample(ctypes.Structure):
    """`TensegrityCommand`: the first `count` entries, applied or rejected together."""

    _fields_ = [("count", u32), ("reserved", u32), ("entries", CommandEntry * MAX_ACTUATORS)]

    @staticmethod
    def type_name() -> str:
        return "TensegrityCommand"


class LockstepRequest(ctypes.Structure):
    """`TensegrityLockstepRequest`: reset if `flags` say so (its episode from `seed` with
    LOCKSTEP_SEEDED), apply `command`, take `steps` steps, answer the state."""

    _fields_ = [("steps", u64), ("flags", u32), ("reserved", u32), ("seed", u64), ("command", CommandSample)]

    @staticmethod
    def type_name() -> str:
        return "TensegrityLockstepRequest"


class LockstepResponse(ctypes.Structure):
    """`TensegrityLockstepResponse`: result code, steps taken, message, state."""

    _fields_ = [
        ("result", u8),
        ("reserved", u8 * 7),
        ("steps_taken", u64),
        ("message", u8 * MESSAGE_BYTES),
        ("state", StateSample),
    ]

    @staticmethod
    def type_name() -> str:
        return "TensegrityLockstepResponse"


def text(field) -> str:
    """The text of a NUL-terminated name field."""
    raw = bytes(field)
    return raw[: raw.index(0) if 0 in raw else len(raw)].decode("utf-8")


def entry(actuator, rest_length=None, rate=None, tension=None):
    """A command entry for an actuator index or name, with a rest length (m) and/or rate (m/s),
    or a tension (N) alone for a winch actuator's motor."""
    e = CommandEntry()
    if isinstance(actuator, str):
        e.actuator = BY_NAME
        data = actuator.encode("utf-8")[: NAME_BYTES - 1]
        ctypes.memmove(e.name, data, len(data))
    else:
        e.actuator = actuator
    if rest_length is not None:
        e.fields |= FIELD_REST_LENGTH
        e.rest_length = rest_length
    if rate is not None:
        e.fields |= FIELD_RATE
        e.rate = rate
    if tension is not None:
        e.fields |= FIELD_TENSION
        e.tension = tension
    return e


def packed_commands(entries):
    """The bytes of a `CommandSample` holding `entries` (`entry(...)`s), as the in-process
    simulator's lockstep takes them; None when there are none."""
    if not entries:
        return None
    sample = CommandSample()
    TensegrityClient._fill(sample, list(entries))
    return ctypes.string_at(ctypes.addressof(sample), ctypes.sizeof(sample))


class LockstepRefused(RuntimeError):
    """The node refused a lockstep request (code and reason)."""


class Answer:
    """A lockstep answer, read in place from shared memory (valid while this object lives)."""

    def __init__(self, response):
        self._response = response
        self.payload = response.payload().contents
        self.state = self.payload.state


class TensegrityClient:
    """A controller's connection to a node's shared-memory services under `prefix`."""

    def __init__(self, prefix="tensegrity_sim", timeout=10.0, spin_us=200):
        self.prefix = prefix
        self.spin = spin_us * 1e-6
        # iceoryx2 warns that it found no config file; errors still show (IOX2_LOG_LEVEL overrides)
        iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
        self.node = (
            iox2.NodeBuilder.new()
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )
        deadline = time.monotonic() + timeout
        while True:
            try:
                self._open()
                break
            except Exception as e:  # the node may still be creating its services
                if time.monotonic() > deadline:
                    raise RuntimeError(f"no node at '{prefix}': {e}") from e
                time.sleep(0.005)

    def _service(self, name):
        return self.node.service_builder(iox2.ServiceName.new(f"{self.prefix}/{name}"))

    def _open(self):
        # the node creates every service, then its ports: a request sent before its lockstep
        # server exists, or a command before its subscriber, would be lost, so wait for them
        ready = (
            self._service("lockstep").request_response(LockstepRequest, LockstepResponse).open()
            .dynamic_config.number_of_servers > 0
            and self._service("actuator_commands").publish_subscribe(CommandSample).open()
            .dynamic_config.number_of_subscribers > 0
            and self._service("to_node").event().open().dynamic_config.number_of_listeners > 0
            and self._service("state").publish_subscribe(StateSample).open()
            .dynamic_config.number_of_publishers > 0
        )
        if not ready:
            raise RuntimeError("the node's ports are not created yet")
        self.state_sub = (
            self._service("state").publish_subscribe(StateSample).open().subscriber_builder().create()
        )
        self.structure_sub = (
            self._service("structure")
            .publish_subscribe(StructureSample)
            .open()
            .subscriber_builder()
            .create()
        )
        self.command_pub = (
            self._service("actuator_commands")
            .publish_subscribe(CommandSample)
            .open()
            .publisher_builder()
            .create()
        )
        self.lockstep_client = (
            self._service("lockstep")
            .request_response(LockstepRequest, LockstepResponse)
            .open()
            .client_builder()
            .create()
        )
        self.wake_node = self._service("to_node").event().open().notifier_builder().create()
        self.updates = self._service("from_node").event().open().listener_builder().create()
        # only a scene with contacts has this service (the node creates it before the others)
        try:
            self.contacts_sub = (
                self._service("contacts").publish_subscribe(ContactsSample).open().subscriber_builder().create()
            )
        except Exception:
            self.contacts_sub = None
        # likewise the sensors' service, for a scene with [sensors]
        try:
            self.measured_sub = (
                self._service("measured").publish_subscribe(MeasuredSample).open().subscriber_builder().create()
            )
        except Exception:
            self.measured_sub = None

    def _wait(self, ready, timeout):
        """Polls `ready()` for the spin time, then blocks on the node's events until `timeout`.

        Between polls it yields the core, so a node that shares it is not held up (as the Rust
        client does)."""
        start = time.monotonic()
        while time.monotonic() - start < min(self.spin, timeout):
            got = ready()
            if got is not None:
                return got
            os.sched_yield()
        while True:
            got = ready()
            if got is not None:
                return got
            left = timeout - (time.monotonic() - start)
            if left <= 0:
                return None
            self.updates.timed_wait(iox2.Duration.from_secs_f64(min(left, 0.05)))

    def structure(self, timeout=10.0):
        """Scene name, step and names in array order (a dict)."""
        deadline = time.monotonic() + timeout
        asked = 0.0
        while True:
            sample = self.structure_sub.receive()
            if sample is not None:
                break
            if time.monotonic() > deadline:
                raise TimeoutError(f"no structure from '{self.prefix}'")
            if time.monotonic() - asked > 0.1:  # wake a paused node to hand it over
                self.wake_node.notify_with_custom_event_id(iox2.EventId.new(EVENT_HELLO))
                asked = time.monotonic()
            time.sleep(0.001)
        s = sample.payload().contents
        return {
            "scene_name": text(s.scene_name),
            "physics_dt": s.physics_dt,
            "body_names": [text(s.body_names[i]) for i in range(s.body_count)],
            "cable_names": [text(s.cable_names[i]) for i in range(s.cable_count)],
            "actuator_names": [text(s.actuator_names[i]) for i in range(s.actuator_count)],
            "actuator_cable": [s.actuator_cable[i] for i in range(s.actuator_count)],
            "actuator_min_rest_length": [s.actuator_min_rest_length[i] for i in range(s.actuator_count)],
            "actuator_max_rest_length": [s.actuator_max_rest_length[i] for i in range(s.actuator_count)],
            "actuator_max_rate": [s.actuator_max_rate[i] for i in range(s.actuator_count)],
            "contacts": [(text(s.contact_point[i]), text(s.contact_with[i])) for i in range(s.contact_count)],
        }

    def next_state(self, timeout=1.0):
        """A copy of the next unread state sample, or None after `timeout` seconds."""

        def ready():
            sample = self.state_sub.receive()
            if sample is None:
                return None
            copy = StateSample()
            ctypes.memmove(ctypes.byref(copy), sample.payload_ptr, ctypes.sizeof(StateSample))
            return copy

        return self._wait(ready, timeout)

    def latest_contacts(self):
        """A copy of the newest contacts sample received (older ones are released), or None when
        none arrived or the scene has no contacts. After a lockstep answer it is that answer's
        step: the node publishes the contacts first."""
        if self.contacts_sub is None:
            return None
        newest = None
        while True:
            sample = self.contacts_sub.receive()
            if sample is None:
                break
            newest = ContactsSample()
            ctypes.memmove(ctypes.byref(newest), sample.payload_ptr, ctypes.sizeof(ContactsSample))
        return newest

    def latest_measured(self):
        """A copy of the newest sensors sample received (older ones are released), or None when
        none arrived or the scene declares no sensors. After a lockstep answer it is that
        answer's step: the node publishes it before the answer."""
        if self.measured_sub is None:
            return None
        newest = None
        while True:
            sample = self.measured_sub.receive()
            if sample is None:
                break
            newest = MeasuredSample()
            ctypes.memmove(ctypes.byref(newest), sample.payload_ptr, ctypes.sizeof(MeasuredSample))
        return newest

    @staticmethod
    def _fill(command, entries):
        if len(entries) > MAX_ACTUATORS:
            raise ValueError(f"{len(entries)} entries, more than MAX_ACTUATORS = {MAX_ACTUATORS}")
        command.count = len(entries)
        command.reserved = 0
        for i, e in enumerate(entries):
            command.entries[i] = e

    def send_command(self, entries):
        """Sends one command message (applied at the node's next step, or rejected whole)."""
        sample = self.command_pub.loan_uninit()
        self._fill(sample.payload().contents, entries)
        sample.assume_init().send()
        self.wake_node.notify_with_custom_event_id(iox2.EventId.new(EVENT_COMMAND))

    def lockstep(self, steps, entries=(), timeout=10.0, reset=False, seed=None):
        """Applies `entries`, takes `steps` steps and returns the `Answer` (node paused only).
        With `reset`, the node resets first, its episode (the scene's randomization, the sensors'
        streams) drawn from `seed` (an integer from 0 to 2**64 - 1) when given."""
        return self.lockstep_end(self.lockstep_begin(steps, entries, reset, seed), timeout)

    def lockstep_begin(self, steps, entries=(), reset=False, seed=None):
        """Sends a `lockstep` request and returns at once: the node steps while the caller does
        other work (another node's request: several nodes then step in parallel). Pass what it
        returns to `lockstep_end`."""
        if seed is not None and not reset:
            raise ValueError("a seed is for a reset: lockstep(..., reset=True, seed=...)")
        request = self.lockstep_client.loan_uninit()
        payload = request.payload().contents
        payload.steps = steps
        payload.flags = (LOCKSTEP_RESET if reset else 0) | (LOCKSTEP_SEEDED if seed is not None else 0)
        payload.reserved = 0
        payload.seed = 0 if seed is None else seed
        self._fill(payload.command, entries)
        pending = request.assume_init().send()
        self.wake_node.notify_with_custom_event_id(iox2.EventId.new(EVENT_LOCKSTEP))
        return pending

    def lockstep_end(self, pending, timeout=10.0):
        """The `Answer` to a request `lockstep_begin` sent, once it arrives within `timeout` s; a
        refusal raises `LockstepRefused`."""
        response = self._wait(pending.receive, timeout)
        if response is None:
            raise TimeoutError(f"no lockstep answer from '{self.prefix}' within {timeout} s")
        answer = Answer(response)
        if answer.payload.result != RESULT_OK:
            raise LockstepRefused(f"code {answer.payload.result}: {text(answer.payload.message)}")
        return answer


def check(client, target):
    """The self-test of the module docstring; returns the lines to print, raises on failure."""
    names = client.structure()
    assert names["scene_name"], names
    assert names["actuator_names"], "the scene has no actuator"
    first = client.lockstep(10)
    assert first.payload.steps_taken == 10 and first.state.simulation_state == 2, "not paused?"
    step0 = first.state.step
    ring = names["actuator_cable"][0]
    tension0 = first.state.cable_tension[ring]
    rejected0 = first.state.commands_rejected
    del first
    client.send_command([entry(0, rest_length=math.nan)])
    after = client.lockstep(1)
    assert after.state.commands_rejected == rejected0 + 1, "a NaN command was not rejected"
    del after
    try:
        client.lockstep(1, [entry("no_such_winch", rest_length=target)])
        raise AssertionError("a lockstep command for an unknown actuator was obeyed")
    except LockstepRefused as e:
        assert "no_such_winch" in str(e), e
    answer = client.lockstep(1, [entry(names["actuator_names"][0], rest_length=target)])
    times = []
    for _ in range(200):
        t0 = time.perf_counter()
        answer = client.lockstep(1)
        times.append(time.perf_counter() - t0)
    s = answer.state
    assert s.step == step0 + 202, f"step {s.step}, expected {step0 + 202}"
    assert abs(s.actuator_rest_length[0] - target) <= 1e-12 * target, s.actuator_rest_length[0]
    assert s.cable_tension[ring] > tension0, (s.cable_tension[ring], tension0)
    assert all(math.isfinite(s.cable_tension[i]) for i in range(s.cable_count))
    # the state service publishes every step (the test node runs with state_publish_rate 0)
    seen = client.next_state(timeout=1.0)
    assert seen is not None and seen.step <= s.step, "no state sample"
    times.sort()
    return [
        f"OK scene {names['scene_name']} bodies {len(names['body_names'])} cables "
        f"{names['cable_names']} step {s.step} tension {s.cable_tension[ring]:.6g} N",
        f"lockstep 1 step: p50 {1e6 * statistics.median(times):.1f} us, "
        f"p99 {1e6 * times[int(0.99 * len(times)) - 1]:.1f} us",
    ]


def bench(client, n):
    """Times `n` one-step lockstep round trips; returns (p50 s, p99 s, per second)."""
    for _ in range(min(100, n)):
        client.lockstep(1)
    times = []
    start = time.perf_counter()
    for _ in range(n):
        t0 = time.perf_counter()
        client.lockstep(1)
        times.append(time.perf_counter() - t0)
    total = time.perf_counter() - start
    times.sort()
    return statistics.median(times), times[max(0, int(0.99 * n) - 1)], n / total


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--prefix", default="tensegrity_sim", help="<namespace>/<node name>")
    ap.add_argument("--check", type=float, metavar="TARGET", help="run the self-test")
    ap.add_argument("--bench", type=int, metavar="N", help="time N one-step lockstep round trips")
    ap.add_argument("--spin-us", type=float, default=200.0, help="poll before blocking, us")
    ap.add_argument("--sizes", action="store_true", help="print the payload sizes and exit")
    args = ap.parse_args()
    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    if args.sizes:
        for t in (
            StateSample,
            StructureSample,
            CommandEntry,
            CommandSample,
            LockstepRequest,
            LockstepResponse,
            ContactsSample,
            MeasuredSample,
        ):
            print(t.type_name(), ctypes.sizeof(t), ctypes.alignment(t))
        return 0
    client = TensegrityClient(args.prefix, spin_us=args.spin_us)
    if args.check is not None:
        for line in check(client, args.check):
            print(line)
    if args.bench:
        p50, p99, rate = bench(client, args.bench)
        print(f"BENCH n {args.bench} p50_us {1e6 * p50:.2f} p99_us {1e6 * p99:.2f} per_s {rate:.0f}")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except (AssertionError, RuntimeError, TimeoutError) as e:
        print(f"FAILED: {e!r}")
        sys.exit(1)
