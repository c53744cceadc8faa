//! What recording a bag costs the node (run: `cargo bench --bench
//! record_overhead`; `-- --quick` for 10 s of sim time instead of 60, `--seconds N`, `--runs N`
//! (default 2; 0 for the interleaved table alone), `--interleaved-seconds N` (default:
//! `--seconds`; 0 skips that table), `--block-ms A,B,...` (the interleaved table's block
//! lengths, default 100), `--calls-seconds N` (the recorder's calls; default: the interleaved
//! seconds; 0 skips), `--as-fast-as-possible` to step without pacing; the rows serving DDS need
//! `ros2`, those serving shared memory `shm`).
//!
//! The node's core ticks a bundled scene at dt = 1 ms in real time at 1 kHz (each tick at its
//! 1 ms boundary, as the node's loop does) with the state published every step
//! (`state_publish_rate = 0`: every topic, markers at 30 Hz) for 60 s of sim time, serving:
//! nothing (the physics and the core alone), a `BagRecorder` alone (each step's numbers
//! appended to a batch on the node's thread, handed over every `record::BATCH_RECORDS` records;
//! messages built, serialized, compressed and written by the bag's writer thread), DDS (the node
//! as users run it by default, no subscriber) and shared memory alone (the lightest node the
//! binary runs, no controller), each without and with the bag. The configurations alternate; the table gives medians over runs of each run's median, mean and
//! 99th percentile turn time (one `tick`), the node thread's CPU time per step (its own work,
//! including sleeping and waking between ticks) and the process CPU time per step (the writer
//! thread's share too). The bag's size per second of sim time is from the file. Runs a minute
//! apart differ by more than recording costs, so a second table alternates recording on and
//! off in blocks of 100 ms within one run (`run_interleaved`) and compares each recorded block
//! with the blocks beside it. A last table times the recorder's own calls on the node's thread. With `ros2` the bench first moves
//! itself into a private loopback-only network namespace.

#[cfg(feature = "ros2")]
#[path = "../tests/common/netns.rs"]
mod netns;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use tensegrity::io::msg::SimResult;
use tensegrity::io::node::params::NodeParams;
use tensegrity::io::node::runner::{Transport, TransportSinks};
use tensegrity::io::node::NodeCore;
use tensegrity::io::record::{self, BagRecorder, LogTime};
use tensegrity::io::sink::{DiscardSink, NodeSink, NodeView, PublishError};
use tensegrity::io::topics::Topic;
use tensegrity::sim::{SimSettings, Simulator};

/// Process CPU time (user + system) from /proc, s (10 ms ticks).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or("");
    let fields: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // utime and stime are fields 14 and 15 of the line, 12 and 13 after the command name
    (ticks(11) + ticks(12)) / 100.0
}

/// CPU time this thread has run, ns (`/proc/thread-self/schedstat`, first field).
fn thread_cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|f| f.parse().ok()))
        .unwrap_or(0)
}

struct RunFigures {
    /// CPU time of the node's thread per step, us (its own work, whatever else runs).
    thread_cpu_us: f64,
    median_us: f64,
    mean_us: f64,
    p99_us: f64,
    cpu_us: f64,
    bag_bytes: u64,
    messages: u64,
}

/// What the node serves besides the bag.
#[derive(Clone, Copy, PartialEq)]
enum Serving {
    /// Nothing: the physics and the core alone.
    Nothing,
    /// DDS (the node as users run it by default), no subscriber.
    Dds,
    /// Shared memory alone (the lightest node the binary runs), no controller.
    Shm,
}

impl Serving {
    /// Those this build can serve.
    fn built() -> Vec<Serving> {
        let mut all = vec![Serving::Nothing];
        if cfg!(feature = "ros2") {
            all.push(Serving::Dds);
        }
        if cfg!(feature = "shm") {
            all.push(Serving::Shm);
        }
        all
    }

    fn label(self) -> &'static str {
        match self {
            Serving::Nothing => "nothing",
            Serving::Dds => "DDS",
            Serving::Shm => "shm",
        }
    }
}

/// A node as the bench runs it: `scene`'s simulator at the default settings, the core's
/// parameters (no pacing of its own, the state every step), and its transports: what `serving`
/// names (DDS on `domain_id`, shared memory under a prefix of this process's), then a bag in
/// `bag` when given.
struct Setup {
    sim: Simulator,
    params: NodeParams,
    transports: Vec<Box<dyn Transport>>,
}

fn setup(scene: &str, serving: Serving, domain_id: u16, bag: Option<&Path>) -> Setup {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes").join(scene);
    let model = tensegrity::scene::load(&path).unwrap();
    let params = NodeParams { real_time_factor: 0.0, state_publish_rate: 0.0, ..NodeParams::default() };
    let sim = Simulator::new(model.clone(), SimSettings::default()).unwrap();
    let mut transports: Vec<Box<dyn Transport>> = Vec::new();
    match serving {
        Serving::Nothing => {}
        #[cfg(feature = "ros2")]
        Serving::Dds => transports.push(Box::new(
            tensegrity::io::ros2::DdsTransport::new(&NodeParams { domain_id, ..params.clone() }).unwrap(),
        )),
        #[cfg(feature = "shm")]
        Serving::Shm => {
            let prefix = format!("bench_record_{}_{domain_id}", std::process::id());
            let params = NodeParams { shm_prefix_override: Some(prefix), ..params.clone() };
            transports.push(Box::new(tensegrity::io::shm::ShmTransport::new(&model, &params).unwrap()));
        }
        #[allow(unreachable_patterns)]
        _ => unreachable!("{} is not built", serving.label()),
    }
    // (read only by the transports a build without `ros2` and `shm` lacks)
    let _ = domain_id;
    if let Some(dir) = bag {
        let _ = std::fs::remove_dir_all(dir);
        let run = record::run_info(record::KIND_NODE, &model, scene, sim.settings(), &params);
        let recorder =
            BagRecorder::create(dir, &model, &params, &run, LogTime::Wall, &record::node_bag_options())
                .unwrap();
        transports.push(Box::new(recorder));
    }
    Setup { sim, params, transports }
}

fn run(scene: &str, steps: u64, bag: Option<PathBuf>, serving: Serving, paced: bool) -> RunFigures {
    let Setup { sim, params, mut transports } = setup(scene, serving, 90, bag.as_deref());
    let mut core = NodeCore::with_simulator(sim, params);
    let mut nowhere = DiscardSink;
    let mut all = TransportSinks::all(&mut transports);
    let sink: &mut dyn NodeSink =
        if bag.is_some() || serving != Serving::Nothing { &mut all } else { &mut nowhere };
    core.start(sink);
    let mut times = Vec::with_capacity(steps as usize);
    let cpu0 = cpu_seconds();
    let thread0 = thread_cpu_ns();
    let epoch = Instant::now();
    for k in 0..steps {
        if paced {
            sleep_until_tick(epoch, k);
        }
        let t0 = Instant::now();
        core.tick(Duration::from_millis(k), sink);
        times.push(t0.elapsed().as_secs_f64() * 1e6);
    }
    let thread_cpu_us = thread_cpu_ns().saturating_sub(thread0) as f64 * 1e-3 / steps as f64;
    // the bag closes with its transport
    drop(transports);
    let cpu_us = (cpu_seconds() - cpu0) * 1e6 / steps as f64;
    let (mut bag_bytes, mut messages) = (0, 0);
    if let Some(dir) = &bag {
        let info = tensegrity::io::record::bag::BagReader::open(dir).unwrap().info();
        bag_bytes = info.file_bytes;
        messages = info.topics.iter().map(|(_, n)| n).sum();
    }
    assert_eq!(core.stats().steps, steps);
    assert_eq!(core.stats().publish_failures.iter().sum::<u64>(), 0, "nothing dropped");
    let mean_us = times.iter().sum::<f64>() / times.len() as f64;
    times.sort_by(f64::total_cmp);
    RunFigures {
        thread_cpu_us,
        median_us: times[times.len() / 2],
        mean_us,
        p99_us: times[times.len() * 99 / 100],
        cpu_us,
        bag_bytes,
        messages,
    }
}

/// One block of an interleaved run: the mean and the median turn time of its turns, us.
#[derive(Clone, Copy)]
struct Block {
    mean_us: f64,
    median_us: f64,
}

/// The interleaved measurement of one scene and serving: the node's core as in `run`, the bag
/// open the whole time but handed the core's outputs only in alternate blocks of `block` steps
/// (1 ms of sim time each: on, off, on, ...), for `steps` recorded steps. The first `settle`
/// turns of every block are not counted (the writer thread drains what the last recorded block
/// handed it up to `bag::DRAIN_PERIOD` later). Returns the blocks with the bag and those
/// without, in order, and the bag's size, bytes.
fn run_interleaved(
    scene: &str,
    steps: u64,
    block: u64,
    bag: PathBuf,
    serving: Serving,
) -> (Vec<Block>, Vec<Block>, u64) {
    let Setup { sim, params, mut transports } = setup(scene, serving, 91, Some(&bag));
    // the bag is the last transport; the others are served every block
    let served = transports.len() - 1;
    let settle = (block / 10).min(10);
    let mut core = NodeCore::with_simulator(sim, params);
    core.start(&mut TransportSinks::all(&mut transports));
    let (mut on, mut off) = (Vec::new(), Vec::new());
    let mut times = Vec::with_capacity(block as usize);
    let epoch = Instant::now();
    for k in 0..steps.div_ceil(block) * block * 2 {
        sleep_until_tick(epoch, k);
        let recording = (k / block) % 2 == 0;
        let t0 = Instant::now();
        if recording {
            core.tick(Duration::from_millis(k), &mut TransportSinks::all(&mut transports));
        } else if served > 0 {
            core.tick(Duration::from_millis(k), &mut TransportSinks::all(&mut transports[..served]));
        } else {
            core.tick(Duration::from_millis(k), &mut DiscardSink);
        }
        let us = t0.elapsed().as_secs_f64() * 1e6;
        if k % block >= settle {
            times.push(us);
        }
        if k % block == block - 1 {
            let mean_us = times.iter().sum::<f64>() / times.len() as f64;
            let b = Block { mean_us, median_us: median(std::mem::take(&mut times)) };
            if recording {
                on.push(b)
            } else {
                off.push(b)
            }
        }
    }
    drop(transports);
    assert_eq!(core.stats().publish_failures.iter().sum::<u64>(), 0, "nothing dropped");
    let bytes = tensegrity::io::record::bag::BagReader::open(&bag).unwrap().info().file_bytes;
    (on, off, bytes)
}

/// The ratio of each recorded block's `f` to the mean of the unrecorded blocks beside it
/// (recorded block `i` lies between unrecorded blocks `i - 1` and `i`).
fn ratios_to_neighbours(on: &[Block], off: &[Block], f: fn(&Block) -> f64) -> Vec<f64> {
    (0..on.len())
        .filter_map(|i| {
            let beside: Vec<f64> =
                [i.checked_sub(1), Some(i)].into_iter().flatten().filter_map(|j| off.get(j).map(f)).collect();
            (!beside.is_empty()).then(|| f(&on[i]) * beside.len() as f64 / beside.iter().sum::<f64>())
        })
        .collect()
}

/// A transport around another that adds the time spent in its calls to `spent` (ns).
struct Timed {
    inner: Box<dyn Transport>,
    spent: std::rc::Rc<std::cell::Cell<u64>>,
}

impl Timed {
    fn time<R>(&mut self, f: impl FnOnce(&mut dyn Transport) -> R) -> R {
        let t0 = Instant::now();
        let r = f(self.inner.as_mut());
        self.spent.set(self.spent.get() + t0.elapsed().as_nanos() as u64);
        r
    }
}

impl NodeSink for Timed {
    fn publish(&mut self, topic: Topic, view: &NodeView<'_>) -> Result<(), PublishError> {
        self.time(|t| t.publish(topic, view))
    }
    fn step_request_done(&mut self, ticket: u64, result: SimResult, view: &NodeView<'_>) {
        self.time(|t| t.step_request_done(ticket, result, view))
    }
    fn commands_applied(
        &mut self,
        time: f64,
        step: u64,
        commands: &[(tensegrity::model::ActuatorId, tensegrity::control::ActuatorCommand)],
    ) {
        self.time(|t| t.commands_applied(time, step, commands))
    }
    fn simulation_reset(&mut self, time: f64, step: u64, seed: Option<u64>) {
        self.time(|t| t.simulation_reset(time, step, seed))
    }
}

impl Transport for Timed {
    fn name(&self) -> &'static str {
        self.inner.name()
    }
    fn take_inputs(&mut self, core: &mut NodeCore, others: &mut dyn NodeSink) {
        self.time(|t| t.take_inputs(core, others))
    }
    fn takes_inputs(&self) -> bool {
        self.inner.takes_inputs()
    }
}

/// The time a node's turn spends in the recorder's calls (the node's thread's direct cost of
/// recording, without what the writer thread does to it): `scene` paced at 1 kHz for `steps`
/// steps serving only a bag, each call timed (about 20 ns of timer per call is included).
/// Returns the median, the mean (hand-overs to the writer included) and the 99th percentile
/// per turn, us.
fn recorder_calls(scene: &str, steps: u64, bag: PathBuf) -> (f64, f64, f64) {
    let Setup { sim, params, transports } = setup(scene, Serving::Nothing, 92, Some(&bag));
    let spent = std::rc::Rc::new(std::cell::Cell::new(0));
    let mut transports: Vec<Box<dyn Transport>> = transports
        .into_iter()
        .map(|inner| Box::new(Timed { inner, spent: spent.clone() }) as Box<dyn Transport>)
        .collect();
    let mut core = NodeCore::with_simulator(sim, params);
    core.start(&mut TransportSinks::all(&mut transports));
    let mut per_turn = Vec::with_capacity(steps as usize);
    let epoch = Instant::now();
    for k in 0..steps {
        sleep_until_tick(epoch, k);
        let before = spent.get();
        core.tick(Duration::from_millis(k), &mut TransportSinks::all(&mut transports));
        per_turn.push((spent.get() - before) as f64 * 1e-3);
    }
    drop(transports);
    let mean = per_turn.iter().sum::<f64>() / per_turn.len() as f64;
    (median(per_turn.clone()), mean, percentile(per_turn, 99))
}

/// The node's real-time loop: sleeps until tick `k`'s 1 ms boundary after `epoch`.
fn sleep_until_tick(epoch: Instant, k: u64) {
    let due = epoch + Duration::from_millis(k);
    if let Some(wait) = due.checked_duration_since(Instant::now()) {
        std::thread::sleep(wait);
    }
}

/// The `p`-th percentile of `v` (the value at index `len p / 100` of the sorted values).
fn percentile(mut v: Vec<f64>, p: usize) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() * p / 100]
}

fn median(v: Vec<f64>) -> f64 {
    percentile(v, 50)
}

/// The value after `name` in `args`, parsed (`None` when absent or not parseable).
fn option<T: std::str::FromStr>(args: &[String], name: &str) -> Option<T> {
    args.iter().position(|a| a == name).and_then(|k| args.get(k + 1)).and_then(|v| v.parse().ok())
}

fn main() {
    #[cfg(feature = "ros2")]
    if !netns::isolated_or_rerun(
        &std::env::args().skip(1).collect::<Vec<_>>().iter().map(String::as_str).collect::<Vec<_>>(),
    ) {
        return;
    }
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    let seconds: u64 = option(&args, "--seconds").unwrap_or(if quick { 10 } else { 60 });
    let steps = seconds * 1000;
    let runs: usize = option(&args, "--runs").unwrap_or(2);
    let paced = !args.iter().any(|a| a == "--as-fast-as-possible");
    let dir = std::env::temp_dir().join(format!("tensegrity-record-bench-{}", std::process::id()));
    println!(
        "Recording {seconds} s of sim time at dt = 1 ms, state every step, {} ({runs} run(s) of each, alternating; medians)\n",
        if paced { "the node in real time at 1 kHz" } else { "as fast as possible" }
    );
    println!("| scene | serving | node thread CPU per step without / with bag | added | turn time without bag: median / mean / p99 | with bag: median / mean / p99 | CPU per step, all threads, without / with bag | bag per sim second | messages per sim second |");
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    let serving = Serving::built();
    for scene in ["prism3.toml", "tower.toml"].into_iter().filter(|_| runs > 0) {
        for &serving in &serving {
            let mut plain = Vec::new();
            let mut recorded = Vec::new();
            for _ in 0..runs {
                plain.push(run(scene, steps, None, serving, paced));
                recorded.push(run(scene, steps, Some(dir.join(scene)), serving, paced));
            }
            let m = |runs: &[RunFigures], f: fn(&RunFigures) -> f64| median(runs.iter().map(f).collect());
            let (a_thread, a_med, a_mean, a_p99, a_cpu) = (
                m(&plain, |r| r.thread_cpu_us),
                m(&plain, |r| r.median_us),
                m(&plain, |r| r.mean_us),
                m(&plain, |r| r.p99_us),
                m(&plain, |r| r.cpu_us),
            );
            let (b_thread, b_med, b_mean, b_p99, b_cpu) = (
                m(&recorded, |r| r.thread_cpu_us),
                m(&recorded, |r| r.median_us),
                m(&recorded, |r| r.mean_us),
                m(&recorded, |r| r.p99_us),
                m(&recorded, |r| r.cpu_us),
            );
            let bytes = m(&recorded, |r| r.bag_bytes as f64) / seconds as f64;
            let messages = m(&recorded, |r| r.messages as f64) / seconds as f64;
            println!(
                "| {} | {} | {a_thread:.1} / {b_thread:.1} us | {:+.1} % ({:+.1} us) | {a_med:.1} / {a_mean:.1} / {a_p99:.1} us | {b_med:.1} / {b_mean:.1} / {b_p99:.1} us | {a_cpu:.1} / {b_cpu:.1} us | {:.0} kB | {messages:.0} |",
                scene.trim_end_matches(".toml"),
                serving.label(),
                100.0 * (b_thread / a_thread - 1.0),
                b_thread - a_thread,
                bytes / 1000.0,
            );
        }
    }
    let pairs: u64 = option(&args, "--interleaved-seconds").unwrap_or(seconds);
    // block lengths, ms of sim time, comma-separated
    let blocks: Vec<u64> =
        args.iter().position(|a| a == "--block-ms").and_then(|k| args.get(k + 1)).map_or(vec![100], |v| {
            v.split(',').filter_map(|b| b.trim().parse().ok()).filter(|&b| b >= 10).collect()
        });
    if paced && pairs > 0 {
        println!(
            "\nInterleaved: one node, the bag open throughout and handed the node's outputs in alternate blocks of sim time ({pairs} s recorded, {} s run per row; the first tenth of each block, at most 10 turns, not counted); each block's mean and median turn time, and the ratio of each recorded block's to the mean of the two blocks beside it, so that slow drifts of the machine cancel\n",
            2 * pairs
        );
        println!("| scene | serving | block | mean turn time, blocks without / with bag (medians) | added to the mean turn time: median of the block ratios [quartiles] | added to the median turn time: median of the block ratios [quartiles] | recorded blocks whose mean rose more than 10 % | bag per recorded second |");
        println!("| --- | --- | --- | --- | --- | --- | --- | --- |");
        for scene in ["prism3.toml", "tower.toml"] {
            for &serving in &serving {
                for &block in &blocks {
                    let (on, off, bytes) =
                        run_interleaved(scene, pairs * 1000, block, dir.join(scene), serving);
                    let by_mean = ratios_to_neighbours(&on, &off, |b| b.mean_us);
                    let by_median = ratios_to_neighbours(&on, &off, |b| b.median_us);
                    let added = |r: &[f64]| {
                        let pc = |p| 100.0 * (percentile(r.to_vec(), p) - 1.0);
                        format!("{:+.1} % [{:+.1}, {:+.1}]", pc(50), pc(25), pc(75))
                    };
                    let above = by_mean.iter().filter(|&&r| r > 1.1).count();
                    println!(
                        "| {} | {} | {block} ms | {:.1} / {:.1} us | {} | {} | {above} of {} | {:.0} kB |",
                        scene.trim_end_matches(".toml"),
                        serving.label(),
                        median(off.iter().map(|b| b.mean_us).collect()),
                        median(on.iter().map(|b| b.mean_us).collect()),
                        added(&by_mean),
                        added(&by_median),
                        by_mean.len(),
                        bytes as f64 / pairs as f64 / 1000.0,
                    );
                }
            }
        }
    }
    let calls: u64 = option(&args, "--calls-seconds").unwrap_or(pairs);
    if paced && calls > 0 {
        println!(
            "\nThe recorder's own calls on the node's thread (every call timed), {calls} s paced at 1 kHz serving only the bag\n"
        );
        println!("| scene | per turn: median / mean / p99 |");
        println!("| --- | --- |");
        for scene in ["prism3.toml", "tower.toml"] {
            let (p50, mean, p99) = recorder_calls(scene, calls * 1000, dir.join(scene));
            println!("| {} | {p50:.2} / {mean:.2} / {p99:.2} us |", scene.trim_end_matches(".toml"));
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
