//! The bundled six-bar robot rolling in real time at 1 kHz: the node's loop (in-process, serving
//! shared memory) runs `config/scenes/sixbar.toml` from its equilibrium through the winch's haul
//! and the roll onto the next face, paced to the wall clock, and reports how many of its steps
//! ended later than their 1 ms slot allowed (overruns); prism3 (5 us steps) the same way, as the
//! host's own share of late steps. Three runs each, alternated. The longest step is the
//! simulator's own work in its longest step (`NodeStats::longest_step`).
//! Usage: `cargo bench --bench realtime_robot` (`-- --seconds S`, default 6).

use std::time::{Duration, Instant};

use tensegrity::io::node::params::TransportKind;
use tensegrity::testing::SimBuilder;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seconds: f64 =
        args.iter().position(|a| a == "--seconds").and_then(|i| args.get(i + 1)?.parse().ok()).unwrap_or(6.0);
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    println!("| scene | run | wall s | sim s | steps | overruns | overrun share | longest step us |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for (run, scene) in (1..=3).flat_map(|r| [(r, "sixbar"), (r, "prism3")]) {
        let sim = SimBuilder::bundled(scene)
            .real_time()
            .transports(&[TransportKind::Shm])
            .param("start_from_equilibrium", "true")
            .param("follow_schedule", "true")
            .param("shm_prefix", &format!("bench_realtime_robot_{}_{run}", std::process::id()))
            .start()
            .expect("the node starts");
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs_f64(seconds) {
            std::thread::sleep(Duration::from_millis(50));
        }
        let wall = start.elapsed().as_secs_f64();
        let time = sim.latest().time;
        let stats = sim.stop().stats;
        println!(
            "| {scene} | {run} | {wall:.2} | {time:.3} | {} | {} | {:.2} % | {:.0} |",
            stats.steps,
            stats.overruns,
            100.0 * stats.overruns as f64 / stats.steps.max(1) as f64,
            1e6 * stats.longest_step.as_secs_f64()
        );
    }
}
