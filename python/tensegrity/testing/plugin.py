"""pytest plugin (entry point `tensegrity.testing`): the `tensegrity_node` fixture.

    def test_ring(tensegrity_node):                       # bundled prism3, paused, DDS + shm
        state = tensegrity_node.lockstep(10)

    @pytest.mark.tensegrity(paused=False, params={"state_publish_rate": 100})
    def test_real_time(tensegrity_node): ...

The marker's keywords go to `TensegrityNode` (scene, params, paused, transports, timeout). The
node is stopped after the test, passed or failed; a node that did not exit with status 0 fails the
teardown with its stderr. `tensegrity_nodes` is a factory for tests that need several.

Before the first test the plugin moves pytest into a private network namespace whose only
interface is loopback (so no DDS packet leaves the machine). Where the kernel refuses it, DDS is
bound to 127.0.0.1 instead (ROS_LOCALHOST_ONLY=1 for the node, CYCLONEDDS_URI for the test); set
TENSEGRITY_TESTING_NETNS=0 to skip the namespace.
"""

import os

import pytest

from . import netns
from .node import NodeFailed, TensegrityNode

LOCALHOST_CYCLONE = (
    "<CycloneDDS><Domain id='any'><General><Interfaces>"
    "<NetworkInterface address='127.0.0.1' multicast='true'/>"
    "</Interfaces></General></Domain></CycloneDDS>"
)

isolation = "not attempted"


def pytest_configure(config):
    global isolation
    config.addinivalue_line("markers", "tensegrity(**kwargs): keywords of the tensegrity_node fixture's node")
    if os.environ.get("TENSEGRITY_TESTING_NETNS", "1") == "0":
        isolation = "off (TENSEGRITY_TESTING_NETNS=0)"
        return
    try:
        netns.enter_loopback_namespace()
        isolation = "loopback-only network namespace"
    except (OSError, FileNotFoundError) as e:
        isolation = f"127.0.0.1 only (no namespace: {e})"
        os.environ.setdefault("ROS_LOCALHOST_ONLY", "1")
        os.environ.setdefault("CYCLONEDDS_URI", LOCALHOST_CYCLONE)


def pytest_report_header(config):
    return f"tensegrity.testing: DDS isolation: {isolation}"


def _checked_stop(node):
    status = node.stop()
    if status != 0:
        raise NodeFailed(status, node.stderr(), "tensegrity_node ended")


@pytest.fixture
def tensegrity_node(request):
    """A `TensegrityNode` for this test (keywords from the `tensegrity` marker)."""
    marker = request.node.get_closest_marker("tensegrity")
    node = TensegrityNode(**(marker.kwargs if marker else {}))
    try:
        yield node
    finally:
        _checked_stop(node)


@pytest.fixture
def tensegrity_nodes():
    """A factory: `start(**keywords)` gives a `TensegrityNode`; all are stopped after the test."""
    started = []

    def start(**keywords):
        node = TensegrityNode(**keywords)
        started.append(node)
        return node

    try:
        yield start
    finally:
        errors = []
        for node in started:
            try:
                _checked_stop(node)
            except NodeFailed as e:
                errors.append(e)
        if errors:
            raise errors[0]
