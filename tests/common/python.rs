//! The Python the interoperability tests run: `TENSEGRITY_PYTHON` (`bash .ci/test` names
//! target/pyenv, where it installs what they import) or else the system's `python3`.

use std::process::Command;

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
