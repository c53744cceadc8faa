//! Network isolation for everything that opens DDS sockets: re-runs the current executable inside
//! a private network namespace whose only interface is loopback (multicast on, for discovery),
//! through the project's `.ci/loopback-net`, so no packet can leave the machine.

use std::process::Command;

/// Interfaces of this process's network namespace (from /proc, which is per namespace).
pub fn interfaces() -> Vec<String> {
    std::fs::read_to_string("/proc/self/net/dev")
        .unwrap_or_default()
        .lines()
        .skip(2)
        .filter_map(|l| l.split(':').next().map(|s| s.trim().to_string()))
        .collect()
}

/// Returns true when already isolated; otherwise runs this executable again with `args` inside a
/// loopback-only network namespace, asserts that it succeeded, and returns false.
pub fn isolated_or_rerun(args: &[&str]) -> bool {
    if interfaces().iter().all(|i| i == "lo") {
        return true;
    }
    assert!(
        std::env::var_os("TENSEGRITY_NETNS").is_none(),
        "still not isolated inside the namespace: {:?}",
        interfaces()
    );
    let exe = std::env::current_exe().unwrap();
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(".ci/loopback-net");
    let status = Command::new("sh")
        .arg(script)
        .arg(exe)
        .args(args)
        .env("TENSEGRITY_NETNS", "1")
        .status()
        .expect("sh, unshare (util-linux) and ip (iproute2) are needed to isolate DDS processes");
    assert!(status.success(), "{args:?} failed inside its network namespace");
    false
}
