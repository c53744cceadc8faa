"""A test that fails on purpose (tests/python_kit.rs runs it explicitly): the fixture must still
stop its node. Writes the node's process id to $TENSEGRITY_PID_FILE first."""

import os


def test_fails_after_starting_a_node(tensegrity_node):
    with open(os.environ["TENSEGRITY_PID_FILE"], "w") as f:
        f.write(str(tensegrity_node.pid))
    assert tensegrity_node.lockstep(1).step == 1
    assert False, "failing on purpose"
