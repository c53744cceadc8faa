"""A private network namespace whose only interface is loopback, for this process and its children.

DDS discovers peers by multicast on every interface it finds; a test must not send packets off the
machine. `enter_loopback_namespace()` moves the calling process into a new network namespace (and,
when not root, a user namespace that maps the user to root inside, as `unshare --net
--map-root-user` does), brings loopback up with multicast routed to it, and checks that loopback is
the only interface left. The pytest plugin calls it before any test runs: the process must still
be single-threaded (Linux refuses a user namespace to a multithreaded process).
"""

import ctypes
import os
import subprocess

CLONE_NEWUSER = 0x10000000
CLONE_NEWNET = 0x40000000


def interfaces():
    """Names of the network interfaces this process sees (its namespace's)."""
    try:
        with open("/proc/self/net/dev") as f:
            lines = f.read().splitlines()[2:]
    except OSError:
        return []
    return [line.split(":")[0].strip() for line in lines if ":" in line]


def loopback_only():
    """True when loopback is the only interface this process sees."""
    names = interfaces()
    return bool(names) and all(n == "lo" for n in names)


def enter_loopback_namespace():
    """Enters a new loopback-only network namespace unless already in one.

    Raises OSError (with the reason) when the kernel or the tools (`ip` from iproute2) do not allow
    it; the process is then unchanged or, if `ip` failed, in a namespace with no interface up.
    """
    if loopback_only():
        return
    uid, gid = os.getuid(), os.getgid()
    flags = CLONE_NEWNET | (0 if uid == 0 else CLONE_NEWUSER)
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.unshare(flags) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"unshare(CLONE_NEWNET): {os.strerror(err)}")
    if uid != 0:
        with open("/proc/self/setgroups", "w") as f:
            f.write("deny")
        with open("/proc/self/uid_map", "w") as f:
            f.write(f"0 {uid} 1")
        with open("/proc/self/gid_map", "w") as f:
            f.write(f"0 {gid} 1")
    for cmd in (
        ["ip", "link", "set", "lo", "up"],
        ["ip", "link", "set", "lo", "multicast", "on"],
    ):
        subprocess.run(cmd, check=True, capture_output=True)
    subprocess.run(["ip", "route", "add", "224.0.0.0/4", "dev", "lo"], capture_output=True)
    if not loopback_only():
        raise OSError(f"still more than loopback after unshare: {interfaces()}")
