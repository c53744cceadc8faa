//! The Python the interoperability tests run: `TENSEGRITY_PYTHON` (`bash .ci/test` names
//! target/pyenv, where it installs what they import) or else the system's `python3`; and the one
//! the benchmarks look for.

#![allow(dead_code)]

use std::process::Command;

/// For a benchmark: the first of `TENSEGRITY_PYTHON` and target/pyenv that imports `modules`, or
/// `None` (the benchmark then says which rows it left out).
pub fn bench_python_with(modules: &str) -> Option<String> {
    let candidates = [
        std::env::var("TENSEGRITY_PYTHON").ok(),
        Some(format!("{}/target/pyenv/bin/python", env!("CARGO_MANIFEST_DIR"))),
    ];
    candidates.into_iter().flatten().find(|p| {
        Command::new(p).args(["-c", &format!("import {modules}")]).output().is_ok_and(|o| o.status.success())
    })
}

/// The Python that imports `modules` (an import list, `"cyclonedds, iceoryx2"`), or `None` with
/// a SKIPPED note when none was named and the system's cannot. A named Python that cannot is a
/// failure: CI must not skip.
pub fn python_with(modules: &str) -> Option<String> {
    let named = std::env::var("TENSEGRITY_PYTHON").ok();
    let python = named.clone().unwrap_or_else(|| "python3".into());
    let probe = Command::new(&python).args(["-c", &format!("import {modules}")]).output();
    if !probe.map(|o| o.status.success()).unwrap_or(false) {
        assert!(named.is_none(), "TENSEGRITY_PYTHON={python} cannot import {modules}");
        eprintln!("SKIPPED: {python} cannot import {modules} (bash .ci/test installs them in target/pyenv)");
        return None;
    }
    Some(python)
}
