#!/usr/bin/env python3
"""Reads a rosbag2 bag with the independent Python `rosbags` package and prints what it holds as
JSON: per topic its type and message count, and for each message the fields the tests compare.

Usage: read_bag.py BAG_DIR MSG_DIR

Our tensegrity_msgs types are registered from the `.msg` files in MSG_DIR (the repository's
msg/msg), the standard ones come from rosbags' own ROS 2 Jazzy store; nothing is taken from the
bag's schemas, so a wrong definition or encoding in the bag fails here.
"""
import json
import math
import sys
from pathlib import Path

from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore


def num(x):
    x = float(x)
    return None if math.isnan(x) else x


def fields(msgtype, m):
    if msgtype == 'rosgraph_msgs/msg/Clock':
        return {'sec': m.clock.sec, 'nanosec': m.clock.nanosec}
    if msgtype == 'tensegrity_msgs/msg/CableStates':
        return {'stamp': [m.header.stamp.sec, m.header.stamp.nanosec], 'name': list(m.name),
                'tension': [float(t) for t in m.tension], 'rest_length': [float(x) for x in m.rest_length],
                'slack': [bool(b) for b in m.slack],
                'pulley_sticks': [bool(b) for b in m.pulley_sticks],
                'pulley_slip_speed': [float(x) for x in m.pulley_slip_speed],
                'pulley_tension_ratio': [float(x) for x in m.pulley_tension_ratio]}
    if msgtype == 'geometry_msgs/msg/PoseArray':
        return {'frame_id': m.header.frame_id,
                'position': [[p.position.x, p.position.y, p.position.z] for p in m.poses],
                'orientation': [[p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w] for p in m.poses]}
    if msgtype == 'tensegrity_msgs/msg/AppliedCommands':
        return {'step': m.step, 'reset': bool(m.reset), 'name': list(m.name),
                'rest_length': [num(x) for x in m.rest_length], 'rate': [num(x) for x in m.rate],
                'tension': [num(x) for x in m.tension],
                'stamp': [m.header.stamp.sec, m.header.stamp.nanosec]}
    if msgtype == 'sensor_msgs/msg/JointState':
        return {'name': list(m.name), 'position': [float(x) for x in m.position]}
    if msgtype == 'tensegrity_msgs/msg/Structure':
        return {'scene_name': m.scene_name, 'cable_names': list(m.cable_names),
                'randomize_episode': int(m.randomize_episode),
                'randomized_parameter': list(m.randomized_parameter),
                'randomized_value': [float(x) for x in m.randomized_value]}
    if msgtype == 'tf2_msgs/msg/TFMessage':
        return {'child_frame_id': [t.child_frame_id for t in m.transforms]}
    if msgtype == 'diagnostic_msgs/msg/DiagnosticArray':
        return {'level': [int(s.level) for s in m.status]}
    if msgtype == 'visualization_msgs/msg/MarkerArray':
        return {'markers': len(m.markers)}
    if msgtype == 'tensegrity_msgs/msg/ContactStates':
        return {'point': list(m.point), 'ground': list(m.ground), 'in_contact': [bool(b) for b in m.in_contact],
                'normal_force': [float(f) for f in m.normal_force],
                'position': [[p.x, p.y, p.z] for p in m.position],
                'friction': [[f.x, f.y, f.z] for f in m.friction]}
    if msgtype == 'tensegrity_msgs/msg/ImuStates':
        return {'name': list(m.name),
                'angular_velocity': [{'x': v.x, 'y': v.y, 'z': v.z} for v in m.angular_velocity],
                'specific_force': [{'x': v.x, 'y': v.y, 'z': v.z} for v in m.specific_force]}
    if msgtype == 'tensegrity_msgs/msg/SensorReadings':
        return {'channel': list(m.channel), 'count': [int(n) for n in m.count],
                'value': [float(x) for x in m.value], 'lost': [bool(b) for b in m.lost]}
    raise SystemExit(f'unexpected type {msgtype}')


def main():
    bag, msg_dir = Path(sys.argv[1]), Path(sys.argv[2])
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for f in sorted(msg_dir.glob('*.msg')):
        types.update(get_types_from_msg(f.read_text(), f'tensegrity_msgs/msg/{f.stem}'))
    store.register(types)
    out = {'topics': {}, 'messages': {}}
    with AnyReader([bag], default_typestore=store) as reader:
        for c in reader.connections:
            out['topics'][c.topic] = {'type': c.msgtype, 'count': c.msgcount}
            out['messages'].setdefault(c.topic, [])
        for c, _timestamp, raw in reader.messages():
            m = reader.deserialize(raw, c.msgtype)
            out['messages'][c.topic].append(fields(c.msgtype, m))
    json.dump(out, sys.stdout)


if __name__ == '__main__':
    main()
