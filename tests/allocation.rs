//! Invariant: once running, a simulation step allocates no memory — generalized-alpha and
//! symplectic Euler, dense (prism3: LU, and the joints' Schur complement for Euler) and sparse
//! (tower: supernodal LDL^T of the symmetric part, and LU), RK4 and Dormand-Prince, and
//! error-controlled steps (generalized-alpha on prism3 and the tower, Dormand-Prince: sub-steps,
//! refused attempts and the error estimate), with joints, sliding cables, damping and actuation.
//! Recording a step into a bag allocates nothing on the node's thread either, and reading a bag
//! holds about a chunk of it, not the file. A counting global allocator watches the stepping
//! (or reading) thread.

// A global allocator can only be written with `unsafe`; it forwards to `System` unchanged.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::PathBuf;

use std::time::Duration;

use tensegrity::io::node::params::NodeParams;
use tensegrity::io::node::NodeCore;
use tensegrity::io::record::bag::BagOptions;
use tensegrity::io::record::{self, BagRecorder, LogTime};
use tensegrity::io::sink::{DiscardSink, NodeSink};
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::Integrator;
use tensegrity::solve::linear::LinearBackend;

struct Counting;
// per thread: tests run in parallel, each watching its own thread
thread_local!(static ALLOCATIONS: Cell<usize> = const { Cell::new(0) });
thread_local!(static WATCHING: Cell<bool> = const { Cell::new(false) });
// bytes allocated less bytes freed by this thread while `WEIGHING`, and the largest value seen
thread_local!(static LIVE_BYTES: Cell<isize> = const { Cell::new(0) });
thread_local!(static PEAK_BYTES: Cell<isize> = const { Cell::new(0) });
thread_local!(static WEIGHING: Cell<bool> = const { Cell::new(false) });

fn weigh(bytes: isize) {
    if WEIGHING.with(Cell::get) {
        let live = LIVE_BYTES.with(|l| {
            l.set(l.get() + bytes);
            l.get()
        });
        PEAK_BYTES.with(|p| p.set(p.get().max(live)));
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if WATCHING.with(|w| w.get()) {
            ALLOCATIONS.with(|a| a.set(a.get() + 1));
        }
        weigh(layout.size() as isize);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        weigh(-(layout.size() as isize));
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if WATCHING.with(|w| w.get()) {
            ALLOCATIONS.with(|a| a.set(a.get() + 1));
        }
        weigh(new_size as isize - layout.size() as isize);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations_per_run(scene: &str, settings: SimSettings) -> usize {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes").join(scene);
    let model = tensegrity::scene::load(&path).unwrap();
    let mut sim = Simulator::new(model, settings).unwrap();
    for _ in 0..5 {
        sim.step().unwrap(); // warm-up: first factorizations size their storage
    }
    let before = ALLOCATIONS.with(Cell::get);
    WATCHING.with(|w| w.set(true));
    for _ in 0..100 {
        sim.step().unwrap();
    }
    WATCHING.with(|w| w.set(false));
    ALLOCATIONS.with(Cell::get) - before
}

#[test]
fn stepping_allocates_nothing() {
    let ga = |linear| SimSettings {
        dt: 1e-3,
        integrator: Integrator::GeneralizedAlpha { rho_inf: 0.8 },
        linear,
        ..Default::default()
    };
    let euler = |linear| SimSettings {
        dt: 5e-4,
        integrator: Integrator::SymplecticEuler,
        linear,
        ..Default::default()
    };
    let explicit = |integrator, dt| SimSettings { dt, integrator, ..Default::default() };
    let controlled =
        |integrator| SimSettings { dt: 1e-3, integrator, tolerance: Some(1e-6), ..Default::default() };
    for (scene, settings, what) in [
        ("prism3.toml", explicit(Integrator::Rk4, 1e-3), "RK4"),
        ("prism3.toml", explicit(Integrator::DormandPrince, 1e-3), "Dormand-Prince"),
        ("prism3.toml", controlled(Integrator::DormandPrince), "Dormand-Prince, error-controlled"),
        (
            "prism3.toml",
            controlled(Integrator::GeneralizedAlpha { rho_inf: 0.8 }),
            "generalized-alpha, error-controlled",
        ),
        (
            "tower.toml",
            controlled(Integrator::GeneralizedAlpha { rho_inf: 0.8 }),
            "generalized-alpha, error-controlled, tower",
        ),
        ("prism3.toml", ga(LinearBackend::Dense), "generalized-alpha, dense"),
        ("prism3.toml", euler(LinearBackend::Dense), "symplectic Euler, dense"),
        ("tower.toml", ga(LinearBackend::Sparse), "generalized-alpha, sparse"),
        ("tower.toml", euler(LinearBackend::Sparse), "symplectic Euler, sparse"),
        ("tower.toml", ga(LinearBackend::SparseLu), "generalized-alpha, sparse LU only"),
        ("tower.toml", euler(LinearBackend::SparseLu), "symplectic Euler, sparse LU only"),
        ("../examples/capstan.toml", ga(LinearBackend::Auto), "generalized-alpha, pulley friction"),
        ("../examples/capstan.toml", explicit(Integrator::Rk4, 1e-3), "RK4, pulley friction"),
        (
            "../examples/capstan.toml",
            controlled(Integrator::GeneralizedAlpha { rho_inf: 0.8 }),
            "generalized-alpha, error-controlled, pulley friction",
        ),
        ("../examples/hoist.toml", explicit(Integrator::GeneralizedAlpha { rho_inf: 0.8 }, 1e-5), "a winch"),
        ("../examples/hoist.toml", explicit(Integrator::Rk4, 1e-5), "RK4, a winch"),
    ] {
        let n = allocations_per_run(scene, settings);
        assert_eq!(n, 0, "{scene} with {what}: {n} allocations in 100 steps");
    }
}

/// Allocations on this thread while `core` ticks 96 more times into `sink`, one tick a
/// millisecond as a real-time node at 1 kHz (about 19 of the recorder's batches: hand-overs,
/// batches the writer gave back, and the markers' points included).
fn allocations_per_ticks(core: &mut NodeCore, next: &mut u64, sink: &mut dyn NodeSink) -> usize {
    let before = ALLOCATIONS.with(Cell::get);
    WATCHING.with(|w| w.set(true));
    for _ in 0..96 {
        core.tick(Duration::from_millis(*next), sink);
        *next += 1;
        std::thread::sleep(Duration::from_millis(1));
    }
    WATCHING.with(|w| w.set(false));
    ALLOCATIONS.with(Cell::get) - before
}

/// Recording a step into a bag allocates nothing on the node's thread once the writer gives
/// batches back (a real-time node: the writer takes its queue every `bag::DRAIN_PERIOD`): the
/// state goes into a recycled batch of fixed capacity (`record::StepBatch`).
/// prism3 with its state every step and the markers at 30 Hz; the core serving nothing is the
/// baseline.
#[test]
fn recording_a_step_allocates_nothing_on_the_node_thread() {
    // and the sensors' measuring and packing, with a scene that declares them
    for scene in ["config/scenes/prism3.toml", "config/examples/sensors.toml", "config/examples/imu.toml"] {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(scene);
        let model = tensegrity::scene::load(&path).unwrap();
        let params = NodeParams { real_time_factor: 0.0, state_publish_rate: 0.0, ..NodeParams::default() };
        let sim = Simulator::new(model.clone(), SimSettings::default()).unwrap();
        let dir = std::env::temp_dir().join(format!("tensegrity-allocation-bag-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let run = record::run_info(record::KIND_NODE, &model, scene, sim.settings(), &params);
        let mut recorder =
            BagRecorder::create(&dir, &model, &params, &run, LogTime::Step, &BagOptions::default()).unwrap();
        let mut core = NodeCore::with_simulator(sim, params);
        core.start(&mut recorder);
        let mut next = 0;
        let baseline = allocations_per_ticks(&mut core, &mut next, &mut DiscardSink);
        // warm-up: the writer's first batches are new
        allocations_per_ticks(&mut core, &mut next, &mut recorder);
        let recording = allocations_per_ticks(&mut core, &mut next, &mut recorder);
        recorder.finish().unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(baseline, 0, "{scene}: the core alone allocates {baseline} times in 96 ticks");
        assert_eq!(recording, 0, "{scene}: recording allocates {recording} times in 96 ticks");
    }
}

/// A bag of 24 MiB (384 messages of 64 KiB that zstd cannot shrink, in chunks of 1 MiB): reading
/// every message, its info, its run record and its topics holds at most 2 MiB at a time on the
/// reading thread (0.27 MB measured). Before the reader streamed, it held the whole file (25.5
/// MB).
#[test]
fn reading_a_bag_holds_about_a_chunk_not_the_file() {
    use tensegrity::io::record::bag::{BagReader, BagTopic, BagWriter, TopicSpec};
    use tensegrity::io::topics::TopicQos;
    let dir = std::env::temp_dir().join(format!("tensegrity-alloc-bag-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let topics = vec![TopicSpec {
        name: "/clock".into(),
        type_name: "rosgraph_msgs/msg/Clock".into(),
        qos: TopicQos { depth: 10, transient_local: false },
    }];
    let mut writer = BagWriter::create(&dir, topics, &Default::default(), &BagOptions::default()).unwrap();
    let (count, size) = (384u32, 64 * 1024);
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    for k in 0..count {
        // xorshift bytes after a CDR header: incompressible
        let mut data = vec![0u8, 1, 0, 0];
        data.extend((0..size).map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u8
        }));
        writer.write_serialized(BagTopic(0), k, u64::from(k) * 1_000_000, data, false).unwrap();
    }
    writer.finish().unwrap();

    LIVE_BYTES.with(|l| l.set(0));
    PEAK_BYTES.with(|p| p.set(0));
    WEIGHING.with(|w| w.set(true));
    let reader = BagReader::open(&dir).unwrap();
    let (mut read, mut bytes) = (0u32, 0usize);
    for m in reader.messages() {
        let m = m.unwrap();
        read += 1;
        bytes += m.data.len();
    }
    let info = reader.info();
    let complete = reader.complete();
    let (run, declared) = (reader.run(), reader.declared_topics());
    WEIGHING.with(|w| w.set(false));
    let peak = PEAK_BYTES.with(Cell::get);
    let _ = std::fs::remove_dir_all(&dir);

    assert_eq!((read, bytes), (count, count as usize * (size + 4)));
    assert!(info.file_bytes > 24 << 20, "the bag is {} bytes", info.file_bytes);
    assert_eq!(info.topics[0].1, u64::from(count));
    assert!(complete && info.cut_short.is_none() && run.is_some() && declared.len() == 1);
    assert!(peak < 2 << 20, "reading held {peak} bytes at once, of a {} byte bag", info.file_bytes);
}
