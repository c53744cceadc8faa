//! Scratch files that go when the test binary exits (`remove_at_exit`), shared by the tests and
//! the benchmarks that include `peer.rs`.
#![allow(dead_code)]

/// Paths `remove_at_exit` was given.
static AT_EXIT: std::sync::Mutex<Vec<std::path::PathBuf>> = std::sync::Mutex::new(Vec::new());

/// Removes `path` (a file or a directory tree) when the test binary exits, passed or failed (the
/// harness ends with `exit`, which runs `atexit` handlers; an interrupted run is `.ci/test`'s to
/// clean). `TENSEGRITY_KEEP_SCRATCH=1` keeps everything, for a look after a failure.
pub fn remove_at_exit(path: &std::path::Path) {
    extern "C" fn remove_all() {
        let paths = std::mem::take(&mut *AT_EXIT.lock().unwrap_or_else(|p| p.into_inner()));
        for p in paths {
            let _ = std::fs::remove_dir_all(&p).or_else(|_| std::fs::remove_file(&p));
        }
    }
    static REGISTER: std::sync::Once = std::sync::Once::new();
    if std::env::var_os("TENSEGRITY_KEEP_SCRATCH").is_some() {
        return;
    }
    // SAFETY: registers a plain function with no arguments; it only takes a lock and removes files
    #[allow(unsafe_code)]
    REGISTER.call_once(|| unsafe {
        libc::atexit(remove_all);
    });
    AT_EXIT.lock().unwrap_or_else(|p| p.into_inner()).push(path.to_path_buf());
}
