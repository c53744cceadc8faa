"""Round trips to the node's simulation_interfaces services from Eclipse Cyclone DDS (an independent
DDS implementation), with rmw_cyclonedds' request/reply layout, and command-to-effect over DDS.

Usage: dds_services_cyclone.py services DOMAIN NAMESPACE N
       dds_services_cyclone.py commands DOMAIN NAMESPACE N

`services` times N StepSimulation(1) and N GetSimulationState calls on a paused node started with
`-p service_mapping:=cyclone` (alternating the two); `commands` times N actuator commands on a
playing node, from the write to the first ~/cable_states sample that carries the new rest
length. The client waits on a Cyclone WaitSet (it blocks; it does not spin). Prints one line per
measurement: `name p50_us p99_us n`. Run by `cargo bench --bench dds_services`.
"""

import os
import sys
import time
from dataclasses import dataclass

from cyclonedds.core import Policy, Qos, ReadCondition, SampleState, ViewState, InstanceState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import int32, uint8, uint32, uint64
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "interop"))
from cyclone_controller import ActuatorCommand, CableStates, Header, Time  # noqa: E402

# rmw_cyclonedds puts a 16-byte header before every request and reply: the lower 8 bytes of the
# client's GUID and the request's sequence number (high, low). The node answers with the same.


@dataclass
class StepRequest(IdlStruct, typename="simulation_interfaces::srv::dds_::StepSimulation_Request_"):
    guid: uint64
    seq_high: int32
    seq_low: uint32
    steps: uint64


@dataclass
class StepReply(IdlStruct, typename="simulation_interfaces::srv::dds_::StepSimulation_Response_"):
    guid: uint64
    seq_high: int32
    seq_low: uint32
    result: uint8
    error_message: str


@dataclass
class GetStateRequest(IdlStruct, typename="simulation_interfaces::srv::dds_::GetSimulationState_Request_"):
    guid: uint64
    seq_high: int32
    seq_low: uint32
    structure_needs_at_least_one_member: uint8


@dataclass
class GetStateReply(IdlStruct, typename="simulation_interfaces::srv::dds_::GetSimulationState_Response_"):
    guid: uint64
    seq_high: int32
    seq_low: uint32
    state: uint8
    result: uint8
    error_message: str


GUID = 0x5445_4E53_4547_5259  # any value: it only pairs replies with this client
QOS = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(10))
ANY = SampleState.Any | ViewState.Any | InstanceState.Any


class Service:
    """One service's request writer and reply reader, with a wait set on the replies."""

    def __init__(self, participant, namespace, name, request_type, reply_type):
        self.request_type = request_type
        rq = Topic(participant, f"rq{namespace}/{name}Request", request_type)
        rr = Topic(participant, f"rr{namespace}/{name}Reply", reply_type)
        self.writer = DataWriter(participant, rq, qos=QOS)
        self.reader = DataReader(participant, rr, qos=QOS)
        self.waitset = WaitSet(participant)
        self.waitset.attach(ReadCondition(self.reader, ANY))
        self.seq = 0

    def call(self, timeout, **fields):
        """Sends one request and returns its reply, or None after `timeout` seconds."""
        self.seq += 1
        self.writer.write(self.request_type(guid=GUID, seq_high=0, seq_low=self.seq, **fields))
        deadline = time.monotonic() + timeout
        while True:
            for reply in self.reader.take(N=8):
                if reply.guid == GUID and reply.seq_low == self.seq:
                    return reply
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.waitset.wait(duration(microseconds=max(1, int(left * 1e6))))


def quantiles(name, samples_us):
    s = sorted(samples_us)
    q = lambda p: s[round((len(s) - 1) * p)]  # noqa: E731
    print(f"{name} {q(0.5):.1f} {q(0.99):.1f} {len(s)}", flush=True)


def services(participant, namespace, n):
    step = Service(participant, namespace, "step_simulation", StepRequest, StepReply)
    get = Service(participant, namespace, "get_simulation_state", GetStateRequest, GetStateReply)
    # discovery: retry until both services answer
    deadline = time.monotonic() + 20
    while step.call(0.5, steps=1) is None or get.call(0.5, structure_needs_at_least_one_member=0) is None:
        if time.monotonic() > deadline:
            print("FAIL the node's services did not answer", flush=True)
            return 1
    for _ in range(20):
        step.call(5, steps=1)
        get.call(5, structure_needs_at_least_one_member=0)
    t_step, t_get = [], []

    def timed(service, times, name, **fields):
        """One call's round trip into `times`, us; False (after saying so) unless it succeeded."""
        s = time.perf_counter()
        r = service.call(5, **fields)
        times.append((time.perf_counter() - s) * 1e6)
        if r is None or r.result != 1:
            print(f"FAIL {name} answered {r}", flush=True)
            return False
        return True

    for _ in range(n):
        if not (timed(step, t_step, "StepSimulation", steps=1)
                and timed(get, t_get, "GetSimulationState", structure_needs_at_least_one_member=0)):
            return 1
    quantiles("cyclone_step_simulation", t_step)
    quantiles("cyclone_get_simulation_state", t_get)
    return 0


def commands(participant, namespace, n):
    cables_topic = Topic(participant, f"rt{namespace}/cable_states", CableStates)
    commands_topic = Topic(participant, f"rt{namespace}/actuator_commands", ActuatorCommand)
    cables = DataReader(participant, cables_topic, qos=Qos(Policy.Reliability.Reliable(duration(seconds=1)),
                                                           Policy.History.KeepLast(100)))
    writer = DataWriter(participant, commands_topic, qos=QOS)
    waitset = WaitSet(participant)
    waitset.attach(ReadCondition(cables, ANY))
    deadline = time.monotonic() + 20
    first = None
    while first is None:
        got = cables.take(N=100)
        first = got[-1] if got else None
        if time.monotonic() > deadline:
            print("FAIL no ~/cable_states", flush=True)
            return 1
        waitset.wait(duration(milliseconds=50))
    ring = list(first.name).index("ring")
    l0 = first.rest_length[ring]
    time.sleep(0.5)  # the node's reader matches the writer
    t = []
    for k in range(n + 20):
        target = l0 - 1e-5 * (k % 2 + 1)
        cables.take(N=1000)
        s = time.perf_counter()
        writer.write(ActuatorCommand(Header(Time(0, 0), ""), ["ring_winch"], [target], []))
        seen = None
        while seen is None and time.perf_counter() - s < 2.0:
            for m in cables.take(N=100):
                if abs(m.rest_length[ring] - target) < 1e-12:
                    seen = time.perf_counter()
            if seen is None:
                waitset.wait(duration(milliseconds=10))
        if seen is None:
            print(f"FAIL command {k} not reflected within 2 s", flush=True)
            return 1
        if k >= 20:
            t.append((seen - s) * 1e6)
    quantiles("cyclone_command_to_effect", t)
    return 0


def main():
    what, domain, namespace, n = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4])
    participant = DomainParticipant(domain)
    return services(participant, namespace, n) if what == "services" else commands(participant, namespace, n)


if __name__ == "__main__":
    sys.exit(main())
