//! How the kit keeps DDS tests apart and on this machine: takes the calling test, gives a re-run
//! of it inside a private network namespace whose only interface is loopback (`unshare`, `ip`),
//! and leases DDS domain ids (`DomainLease`, lock files shared by every process on the machine).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::error::KitError;

/// DDS domain ids the kit leases (`DomainLease`): above the ids our own tests use (61-78), up
/// to the largest whose ports fit (232).
pub const LEASED_DOMAINS: std::ops::RangeInclusive<u16> = 101..=232;

/// Interfaces of this process's network namespace (from /proc, which is per namespace).
pub fn network_interfaces() -> Vec<String> {
    std::fs::read_to_string("/proc/self/net/dev")
        .unwrap_or_default()
        .lines()
        .skip(2)
        .filter_map(|l| l.split(':').next().map(|s| s.trim().to_string()))
        .collect()
}

/// True when this process's only network interface is loopback.
pub fn network_is_loopback_only() -> bool {
    let all = network_interfaces();
    !all.is_empty() && all.iter().all(|i| i == "lo")
}

/// Shell run by `unshare` inside the new namespace: loopback up, multicast on and routed to it
/// (DDS discovery), then the command.
const LOOPBACK_SETUP: &str = "ip link set lo up && ip link set lo multicast on && \
     { ip route add 224.0.0.0/4 dev lo 2>/dev/null || true; } && exec \"$@\"";

/// For a `#[test]` that opens DDS sockets: returns true when this process is already inside a
/// loopback-only network namespace (run the test body); otherwise runs this test executable again
/// with `--exact test --nocapture --test-threads=1` inside a new one (`unshare --net`, mapping
/// the user to root when not root; needs `unshare` and `ip`), panics if that run failed, and
/// returns false (return at once: the body ran in the child).
///
/// ```no_run
/// #[test]
/// fn my_controller_holds_the_ring() {
///     if !tensegrity::testing::isolated_or_rerun("my_controller_holds_the_ring") {
///         return;
///     }
///     // ... DDS traffic stays on this machine
/// }
/// ```
pub fn isolated_or_rerun(test: &str) -> bool {
    rerun_isolated(&["--exact", test, "--nocapture", "--test-threads=1"])
}

/// Like `isolated_or_rerun`, with the test executable's arguments given whole.
pub fn rerun_isolated(args: &[&str]) -> bool {
    if network_is_loopback_only() {
        return true;
    }
    assert!(
        std::env::var_os("TENSEGRITY_NETNS").is_none(),
        "still not isolated inside the namespace: {:?}",
        network_interfaces()
    );
    let exe = std::env::current_exe().expect("the test executable's path");
    let mut cmd = std::process::Command::new("unshare");
    cmd.arg("--net");
    if !is_root() {
        cmd.arg("--map-root-user");
    }
    die_with_parent(&mut cmd);
    let status = cmd
        .args(["--", "sh", "-c", LOOPBACK_SETUP, "loopback-net"])
        .arg(exe)
        .args(args)
        .env("TENSEGRITY_NETNS", "1")
        .status()
        .expect("unshare (util-linux) and ip (iproute2) are needed to isolate DDS tests");
    assert!(status.success(), "{args:?} failed inside its network namespace ({status})");
    false
}

fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("Uid:")).map(|l| l.split_whitespace().nth(1) == Some("0"))
        })
        .unwrap_or(false)
}

/// A DDS domain id held for one simulator: a lock file `<tmp>/tensegrity-dds-domains/<id>` holding
/// the owner's process id, created exclusively, removed on drop. A file whose process no longer
/// runs is taken over. Every process on the machine (the Rust kit, the Python kit) leases from the
/// same directory, so parallel tests never share a domain.
#[derive(Debug)]
pub struct DomainLease {
    id: u16,
    file: PathBuf,
}

static LEASE_SEQUENCE: AtomicU64 = AtomicU64::new(0);

impl DomainLease {
    /// The directory of the lock files.
    pub fn directory() -> PathBuf {
        std::env::temp_dir().join("tensegrity-dds-domains")
    }

    /// Leases a free id from `LEASED_DOMAINS`, starting at a place that depends on the process
    /// and the call, so parallel callers rarely contend.
    pub fn acquire() -> Result<Self, KitError> {
        let dir = Self::directory();
        std::fs::create_dir_all(&dir)
            .map_err(|e| KitError::Transport(format!("domain leases in {}: {e}", dir.display())))?;
        let (lo, hi) = (*LEASED_DOMAINS.start() as u64, *LEASED_DOMAINS.end() as u64);
        let span = hi - lo + 1;
        let first = (std::process::id() as u64 * 7 + LEASE_SEQUENCE.fetch_add(1, Ordering::Relaxed)) % span;
        for k in 0..span {
            let id = (lo + (first + k) % span) as u16;
            if let Some(lease) = Self::try_take(&dir, id) {
                return Ok(lease);
            }
        }
        Err(KitError::Transport(format!("every DDS domain id {lo}-{hi} is leased ({})", dir.display())))
    }

    /// Takes `id` if its file is absent or left by a process that has ended.
    fn try_take(dir: &Path, id: u16) -> Option<Self> {
        let file = dir.join(id.to_string());
        for _ in 0..2 {
            match std::fs::OpenOptions::new().write(true).create_new(true).open(&file) {
                Ok(mut f) => {
                    use std::io::Write;
                    f.write_all(std::process::id().to_string().as_bytes()).ok()?;
                    return Some(Self { id, file });
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let owner = std::fs::read_to_string(&file).ok()?;
                    let owner: u32 = owner.trim().parse().ok()?;
                    if Path::new(&format!("/proc/{owner}")).exists() {
                        return None;
                    }
                    // stale: its owner is gone (two takers race on create_new, one wins)
                    let _ = std::fs::remove_file(&file);
                }
                Err(_) => return None,
            }
        }
        None
    }

    /// The leased domain id.
    pub fn id(&self) -> u16 {
        self.id
    }
}

impl Drop for DomainLease {
    fn drop(&mut self) {
        let ours =
            std::fs::read_to_string(&self.file).is_ok_and(|s| s.trim() == std::process::id().to_string());
        if ours {
            let _ = std::fs::remove_file(&self.file);
        }
    }
}

/// Makes the process `cmd` spawns receive SIGKILL when the thread that spawned it ends (Linux
/// `PR_SET_PDEATHSIG`; kept across `exec`). A test that is interrupted (Ctrl-C, a timeout's
/// kill) or panics then leaves no child behind, not even one it stopped with SIGSTOP, which no
/// other signal ends. Spawn from the thread that outlives the child (the test's own). When the
/// parent is already gone by the time the child starts, the spawn fails.
pub fn die_with_parent(cmd: &mut std::process::Command) {
    use std::os::unix::process::CommandExt;
    // SAFETY: getpid is async-signal-safe
    #[allow(unsafe_code)]
    let parent = unsafe { libc::getpid() };
    // SAFETY: the closure runs in the child between fork and exec and calls only the
    // async-signal-safe prctl and getppid; it allocates nothing
    #[allow(unsafe_code)]
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if libc::getppid() != parent {
                return Err(std::io::Error::other("the parent ended before the child started"));
            }
            Ok(())
        });
    }
}
