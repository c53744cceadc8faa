//! A process's CPU time from `/proc/PID/stat`, for the tests that check an idle node stays idle
//! and the benchmark that measures it.
#![allow(dead_code)]

/// User plus system CPU time of process `pid`, in clock ticks (`clock_ticks_per_second`).
pub fn cpu_ticks(pid: u32) -> u64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).expect("the process runs");
    // the command name (field 2) may hold spaces: count from the state (field 3) after it
    let after = &stat[stat.rfind(')').expect("a command name") + 2..];
    let fields: Vec<&str> = after.split_whitespace().collect();
    // fields 14 and 15 of stat(5)
    fields[11].parse::<u64>().unwrap() + fields[12].parse::<u64>().unwrap()
}

/// Clock ticks per second (`sysconf(_SC_CLK_TCK)`, 100 on Linux).
pub fn clock_ticks_per_second() -> f64 {
    // SAFETY: sysconf has no preconditions
    #[allow(unsafe_code)]
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    hz as f64
}
