"""A ROS 2 controller written against Eclipse Cyclone DDS (an independent DDS implementation).

Usage: cyclone_controller.py DOMAIN ACTUATOR CABLE_INDEX TARGET_REST_LENGTH

Subscribes to the node's ~/body_poses and ~/cable_states with the ROS 2 type names, then
publishes ~/actuator_commands until a cable state shows the commanded rest length. Prints one
line of results and exits 0 on success, 1 otherwise. Types follow the .msg definitions in field
order (XCDR1, Cyclone's default).
"""

import sys
import time
from dataclasses import dataclass

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64, int32, sequence, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@dataclass
class PoseArray(IdlStruct, typename="geometry_msgs::msg::dds_::PoseArray_"):
    header: Header
    poses: sequence[Pose]


@dataclass
class CableStates(IdlStruct, typename="tensegrity_msgs::msg::dds_::CableStates_"):
    header: Header
    name: sequence[str]
    tension: sequence[float64]
    length: sequence[float64]
    rest_length: sequence[float64]
    strain: sequence[float64]
    slack: sequence[bool]
    segment_count: sequence[uint32]
    segment_length: sequence[float64]
    pulley_slip: sequence[float64]
    pulley_sticks: sequence[bool]
    pulley_slip_speed: sequence[float64]
    pulley_tension_ratio: sequence[float64]


@dataclass
class ActuatorCommand(IdlStruct, typename="tensegrity_msgs::msg::dds_::ActuatorCommand_"):
    header: Header
    name: sequence[str]
    rest_length: sequence[float64]
    rate: sequence[float64]


def main() -> int:
    domain, actuator, cable, target = int(sys.argv[1]), sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
    dp = DomainParticipant(domain)
    state_qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(10))
    cmd_qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(1))
    poses = DataReader(dp, Topic(dp, "rt/tensegrity_sim/body_poses", PoseArray), qos=state_qos)
    cables = DataReader(dp, Topic(dp, "rt/tensegrity_sim/cable_states", CableStates), qos=state_qos)
    commands = DataWriter(dp, Topic(dp, "rt/tensegrity_sim/actuator_commands", ActuatorCommand), qos=cmd_qos)

    deadline = time.monotonic() + 20.0
    n_poses, bodies, first, last = 0, -1, None, None
    while time.monotonic() < deadline and (n_poses == 0 or first is None):
        got_poses = poses.take(N=100)
        if got_poses:
            n_poses += len(got_poses)
            bodies = len(got_poses[0].poses)
        got = cables.take(N=100)
        if got and first is None:
            first = got[0]
        time.sleep(0.005)
    if first is None or n_poses == 0:
        print(f"FAIL no state received (poses {n_poses}, cable states {0 if first is None else 1})")
        return 1

    reached = None
    next_send = 0.0
    while time.monotonic() < deadline and reached is None:
        if time.monotonic() >= next_send:
            commands.write(ActuatorCommand(Header(Time(0, 0), ""), [actuator], [target], []))
            next_send = time.monotonic() + 0.2
        for m in cables.take(N=100):
            last = m
            if abs(m.rest_length[cable] - target) < 1e-9:
                reached = m
        time.sleep(0.002)
    if reached is None:
        seen = None if last is None else last.rest_length[cable]
        print(f"FAIL command not reflected (last rest length {seen})")
        return 1
    print(
        f"OK poses {n_poses} bodies {bodies} cables {list(first.name)} "
        f"tension_before {first.tension[cable]:.6f} tension_after {reached.tension[cable]:.6f} "
        f"stamp {reached.header.stamp.sec}.{reached.header.stamp.nanosec:09d}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
