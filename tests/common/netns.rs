//! Network isolation for everything that opens DDS sockets: the test kit's
//! `tensegrity::testing::rerun_isolated` (a private network namespace whose only interface is
//! loopback, multicast on for discovery), so no packet can leave the machine.

/// Interfaces of this process's network namespace.
#[allow(dead_code)]
pub fn interfaces() -> Vec<String> {
    tensegrity::testing::network_interfaces()
}

/// Returns true when already isolated; otherwise runs this executable again with `args` inside a
/// loopback-only network namespace, asserts that it succeeded, and returns false.
pub fn isolated_or_rerun(args: &[&str]) -> bool {
    tensegrity::testing::rerun_isolated(args)
}
