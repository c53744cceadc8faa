"""Launch-free tests for controllers of the tensegrity simulator: `TensegrityNode` starts
`tensegrity_node` for one test (leased DDS domain, own shared-memory prefix, loopback-only
network namespace where the kernel allows it), `msgs` has the node's message types generated from
msg/, `shm` the zero-copy lockstep client; the pytest plugin gives the `tensegrity_node` fixture.
"""

from .node import EXIT_STATUS, Contact, NodeFailed, State, TensegrityNode, command, find_executable

__all__ = ["EXIT_STATUS", "Contact", "NodeFailed", "State", "TensegrityNode", "command", "find_executable"]
