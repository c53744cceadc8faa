//! Test peers for DDS fault tests: the node as a separate process (so signals, exit codes and its
//! memory can be checked), a controller-side DDS participant with typed helpers, and child
//! processes that play a role (flooder, frozen or churning subscriber) by re-running the current
//! test executable with `TENSEGRITY_ROLE` set.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use ros2_client::{
    Client, Context, Message, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, ServiceMapping,
    ServiceTypeName, Subscription,
};
use tensegrity::io::ros2::{context, qos};

/// The node's private namespace in these tests.
pub const NS: &str = "/tensegrity_sim";

/// Polls `f` every millisecond until it returns `Some` or `timeout` passes.
pub fn wait_for<T>(timeout: Duration, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let start = Instant::now();
    while start.elapsed() < timeout {
        if let Some(v) = f() {
            return Some(v);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    None
}

/// Sends `signal` (e.g. "STOP", "CONT", "INT", "TERM", "KILL") to process `pid`.
pub fn signal(pid: u32, signal: &str) {
    let ok = Command::new("kill").arg(format!("-{signal}")).arg(pid.to_string()).status().unwrap();
    assert!(ok.success(), "kill -{signal} {pid}");
}

/// Resident memory of process `pid`, kB.
pub fn rss_kb(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

/// `tensegrity_node` running as a child process, its stderr in a file.
pub struct NodeProcess {
    pub child: Child,
    log: PathBuf,
}

impl NodeProcess {
    /// Starts the node binary on the bundled scene with `ROS_DOMAIN_ID = domain` and `-p` args,
    /// serving DDS only unless `params` names `transports` (parallel DDS tests would otherwise
    /// share the default shared-memory service names).
    pub fn start(domain: u16, params: &[&str]) -> Self {
        static SEQUENCE: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let n = SEQUENCE.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let log =
            std::env::temp_dir().join(format!("tensegrity-node-{}-{domain}-{n}.log", std::process::id()));
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_tensegrity_node"));
        tensegrity::testing::die_with_parent(&mut cmd);
        cmd.arg("--ros-args");
        if !params.iter().any(|p| p.starts_with("transports:=")) {
            cmd.args(["-p", "transports:=dds"]);
        }
        for p in params {
            cmd.args(["-p", p]);
        }
        let child = cmd
            .env("ROS_DOMAIN_ID", domain.to_string())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .expect("tensegrity_node starts");
        Self { child, log }
    }

    /// The process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// True while the process runs.
    pub fn alive(&mut self) -> bool {
        self.child.try_wait().unwrap().is_none()
    }

    /// Sends `sig` and waits up to 10 s for the exit; returns the status and everything it wrote
    /// to stderr.
    pub fn stop(self, sig: &str) -> (ExitStatus, String) {
        signal(self.pid(), sig);
        self.wait()
    }

    /// Waits up to 10 s for the exit; returns the status and everything it wrote to stderr.
    pub fn wait(mut self) -> (ExitStatus, String) {
        let status =
            wait_for(Duration::from_secs(10), || self.child.try_wait().unwrap()).unwrap_or_else(|| {
                let _ = self.child.kill();
                panic!("the node did not exit within 10 s")
            });
        let stderr = std::fs::read_to_string(&self.log).unwrap_or_default();
        let _ = std::fs::remove_file(&self.log);
        (status, stderr)
    }
}

/// The value after `key ` in the node's closing line ("... commands received 12, accepted ...").
pub fn closing_count(stderr: &str, key: &str) -> u64 {
    let line = stderr.lines().rfind(|l| l.contains("stopped after")).expect("a closing line");
    let rest = &line[line.find(key).unwrap_or_else(|| panic!("'{key}' in '{line}'")) + key.len()..];
    rest.trim_start().split(|c: char| !c.is_ascii_digit()).next().unwrap().parse().unwrap()
}

/// (received, accepted, rejected) commands from the node's closing line.
pub fn closing_counts(stderr: &str) -> (u64, u64, u64) {
    (closing_count(stderr, "received"), closing_count(stderr, "accepted"), closing_count(stderr, "rejected"))
}

/// A DDS participant on the test's side, with typed helpers for the node's topics and services.
pub struct Peer {
    pub node: Node,
    _ctx: Context,
}

impl Peer {
    /// A participant on `domain`, named `name`.
    pub fn new(domain: u16, name: &str) -> Self {
        let ctx = context(domain, false).unwrap();
        let node = ctx.new_node(NodeName::new("/", name).unwrap(), NodeOptions::new()).unwrap();
        Self { node, _ctx: ctx }
    }

    /// A reliable reader with history `depth` on topic `ns/name` of type `pkg/ty`.
    pub fn subscribe<M: serde::de::DeserializeOwned + 'static>(
        &mut self,
        ns: &str,
        name: &str,
        pkg: &str,
        ty: &str,
        depth: usize,
    ) -> Subscription<M> {
        let t = self
            .node
            .create_topic(&Name::new(ns, name).unwrap(), MessageTypeName::new(pkg, ty), &qos(depth, false))
            .unwrap();
        self.node.create_subscription::<M>(&t, Some(qos(depth, false))).unwrap()
    }

    /// A writer on topic `ns/name` with the given QoS.
    pub fn publisher<M: serde::Serialize>(
        &mut self,
        ns: &str,
        name: &str,
        pkg: &str,
        ty: &str,
        q: ros2_client::QosProfile,
    ) -> Publisher<M> {
        let t =
            self.node.create_topic(&Name::new(ns, name).unwrap(), MessageTypeName::new(pkg, ty), &q).unwrap();
        self.node.create_publisher::<M>(&t, Some(q)).unwrap()
    }

    /// A service client of the node's service `name` (`pkg/ty`) with `mapping`.
    pub fn client<Req: Message + Clone + 'static, Resp: Message + 'static>(
        &mut self,
        mapping: ServiceMapping,
        name: &str,
        pkg: &str,
        ty: &str,
    ) -> Client<Req, Resp> {
        self.node
            .create_client(
                mapping,
                &Name::new(NS, name).unwrap(),
                &ServiceTypeName::new(pkg, ty),
                qos(10, false),
                qos(10, false),
            )
            .unwrap()
    }
}

/// Sends one request and waits up to `timeout` for its response.
pub fn call<Req, Resp>(client: &Client<Req, Resp>, req: Req, timeout: Duration) -> Option<Resp>
where
    Req: Message + Clone + 'static,
    Resp: Message + 'static,
{
    let id = client.send_request(req).expect("request sent");
    wait_for(timeout, || match client.receive_response() {
        Ok(Some((rid, r))) if rid == id => Some(r),
        _ => None,
    })
}

/// Sends one request and polls for its response without sleeping (yielding the core between
/// polls), panicking after `timeout`: for timing round trips, where `call`'s 1 ms sleeps would
/// be measured instead.
pub fn call_spinning<Req, Resp>(client: &Client<Req, Resp>, req: Req, timeout: Duration) -> Resp
where
    Req: Message + Clone + 'static,
    Resp: Message + 'static,
{
    let id = client.send_request(req).expect("request sent");
    let start = Instant::now();
    loop {
        match client.receive_response() {
            Ok(Some((rid, r))) if rid == id => return r,
            _ if start.elapsed() > timeout => panic!("no response within {timeout:?}"),
            _ => std::thread::yield_now(),
        }
    }
}

/// A child process running the current test executable's test `test` in role `role` (the test
/// checks `TENSEGRITY_ROLE` first and plays the role), with extra environment `env`.
pub fn spawn_role(test: &str, role: &str, env: &[(&str, String)]) -> Child {
    let mut cmd = Command::new(std::env::current_exe().unwrap());
    cmd.args(["--exact", test, "--nocapture", "--test-threads=1"]).env("TENSEGRITY_ROLE", role);
    tensegrity::testing::die_with_parent(&mut cmd);
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.stdin(Stdio::null()).stdout(Stdio::null()).spawn().expect("role process starts")
}

/// A file path unique to this process and `what`.
pub fn scratch_file(what: &str) -> PathBuf {
    let path = std::env::temp_dir().join(format!("tensegrity-{what}-{}", std::process::id()));
    super::cleanup::remove_at_exit(&path);
    path
}
