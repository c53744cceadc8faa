//! Invariant: the Python package (`tensegrity`, `pip install ./python`: the library, the Gymnasium
//! environments and the test kit) works as its docs say: its own tests (`python/tests`: the
//! library against the command line, the proportional controller in lockstep and in real time,
//! bit-identical lockstep runs under a CPU hog, a refused command, exit statuses of a bad scene
//! and a bad parameter, the Gymnasium environments with the simulator in process and as a node)
//! pass against the installed package and this build's node, and a Python test that fails on purpose still has its node stopped (the process id
//! it wrote is gone afterwards).

#![cfg(all(feature = "ros2", feature = "shm"))]

mod common;
use common::python;

use std::path::PathBuf;
use std::process::Command;

/// `python -m pytest ARGS` with the installed package (its plugin loads by its entry point) and
/// this build's node. The checkout's `python/` is not put on the path: its `tensegrity` has no
/// built extension, so the tests run the package as a user installed it (`bash .ci/test`
/// installs this checkout's wheel).
fn pytest(python: &str, args: &[&str], env: &[(&str, String)]) -> std::process::Output {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut cmd = Command::new(python);
    tensegrity::testing::die_with_parent(&mut cmd);
    cmd.args(["-m", "pytest", "-p", "no:cacheprovider"]);
    cmd.args(args)
        .current_dir(&root)
        .env_remove("PYTHONPATH")
        .env("TENSEGRITY_NODE", env!("CARGO_BIN_EXE_tensegrity_node"));
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("python runs")
}

#[test]
fn the_python_kits_examples_pass_and_a_failing_test_still_stops_its_node() {
    const TEST: &str = "the_python_kits_examples_pass_and_a_failing_test_still_stops_its_node";
    if !tensegrity::testing::isolated_or_rerun(TEST) {
        return;
    }
    let Some(python) = python::python_with("cyclonedds, iceoryx2, gymnasium, pytest, tensegrity._native")
    else {
        return;
    };
    let out = pytest(&python, &["-v", "python/tests"], &[]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("69 passed"), "{text}");

    let pid_file = std::env::temp_dir().join(format!("tensegrity-kit-pid-{}", std::process::id()));
    let _ = std::fs::remove_file(&pid_file);
    let out = pytest(
        &python,
        &["-q", "tests/interop/kit_fails_on_purpose.py"],
        &[("TENSEGRITY_PID_FILE", pid_file.display().to_string())],
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "pytest reports the failure: {text}");
    assert!(text.contains("failing on purpose"), "{text}");
    let pid = std::fs::read_to_string(&pid_file).expect("the test wrote its node's pid");
    let _ = std::fs::remove_file(&pid_file);
    assert!(
        !PathBuf::from(format!("/proc/{}", pid.trim())).exists(),
        "the node (pid {pid}) still runs after the failing test"
    );
}
