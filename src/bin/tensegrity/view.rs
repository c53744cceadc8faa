//! `tensegrity view TARGET`: the browser viewer of a scene (its equilibrium, or its modes
//! animated), a recorded bag, or a running node over shared memory; serves the page on
//! 127.0.0.1 and prints its address.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use clap::Args;
use tensegrity::io::view::{self, FrameStore, ViewGeometry, ViewServer, ViewSource};
use tensegrity::Model;

use crate::output::*;

/// Arguments of `tensegrity view`.
#[derive(Args)]
pub struct ViewArgs {
    /// What to show: a scene file or a bundled scene's name (`sixbar`, `bundled:sixbar`; its
    /// static equilibrium), a bag directory or its .mcap file (replayed), or `node` or
    /// `node:PREFIX` (a running node found over shared memory under its namespace and name,
    /// `tensegrity_sim` by default; give its scene with --scene).
    pub target: String,
    /// The scene file: for a node, the one it was started with (required); for a bag, the scene
    /// it must record (checked by body and cable names; default: the scene the bag carries).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// For a scene: animate its N lowest vibrating modes over the equilibrium (2 s a mode).
    #[arg(long, value_name = "N")]
    pub modes: Option<usize>,
    /// Port on 127.0.0.1 (0: a free one the system chooses; the address is printed).
    #[arg(long, default_value_t = 8765)]
    pub port: u16,
    /// For a bag: most frames kept per simulated second (the steps between are skipped).
    #[arg(long, default_value_t = 60.0)]
    pub fps: f64,
    /// For a node: seconds to wait for it to be there.
    #[arg(long, default_value_t = 5.0)]
    pub timeout: f64,
    /// Stop serving after this many seconds (for scripts; default: until interrupted).
    #[arg(long, value_name = "SECONDS")]
    pub serve_for: Option<f64>,
}

/// What TARGET names.
enum Target {
    Scene(Box<Model>, String),
    Bag(PathBuf),
    Node(String),
}

fn target_of(args: &ViewArgs) -> Result<Target, String> {
    let t = args.target.as_str();
    if t == "node" || t.starts_with("node:") {
        let prefix = t.strip_prefix("node:").unwrap_or("tensegrity_sim").trim_matches('/');
        if prefix.is_empty() {
            return Err(input_error(format!(
                "{t}: the node's prefix is empty (node:NAMESPACE/NAME, or node alone for tensegrity_sim)"
            )));
        }
        return Ok(Target::Node(prefix.to_string()));
    }
    let path = Path::new(t);
    if let Some(name) = t.strip_prefix("bundled:") {
        let model = tensegrity::scene::bundled(name).map_err(|e| input_error(e.to_string()))?;
        return Ok(Target::Scene(Box::new(model), format!("bundled scene {name}")));
    }
    if path.is_dir() || path.extension().is_some_and(|e| e == "mcap") {
        return Ok(Target::Bag(path.to_path_buf()));
    }
    if path.exists() {
        return Ok(Target::Scene(Box::new(load(path)?), t.to_string()));
    }
    if tensegrity::scene::bundled_text(t).is_some() {
        let model = tensegrity::scene::bundled(t).map_err(|e| input_error(e.to_string()))?;
        return Ok(Target::Scene(Box::new(model), format!("bundled scene {t}")));
    }
    let bundled: Vec<&str> = tensegrity::scene::BUNDLED.iter().map(|(n, _)| *n).collect();
    Err(input_error(format!(
        "{t}: no such file, bag directory or bundled scene (bundled: {}; a running node: node or node:PREFIX)",
        bundled.join(", ")
    )))
}

/// Runs `view`.
pub fn run(args: ViewArgs) -> Result<(), String> {
    if !(args.fps > 0.0 && args.fps.is_finite()) {
        return Err(input_error(format!(
            "--fps {}: must be a positive number of frames per simulated second",
            args.fps
        )));
    }
    if !(args.timeout >= 0.0 && args.timeout.is_finite()) {
        return Err(input_error(format!(
            "--timeout {}: must be a non-negative number of seconds",
            args.timeout
        )));
    }
    if let Some(s) = args.serve_for.filter(|s| !(*s >= 0.0 && s.is_finite())) {
        return Err(input_error(format!("--serve-for {s}: must be a non-negative number of seconds")));
    }
    let stop = Arc::new(AtomicBool::new(false));
    match target_of(&args)? {
        Target::Scene(model, label) => {
            if args.scene.is_some() {
                return Err(input_error(
                    "--scene is for a bag or a node; a scene target is its own scene".into(),
                ));
            }
            let geometry = ViewGeometry::new(&model);
            let (state, frame) =
                view::scene::equilibrium(&model, &geometry).map_err(|e| format!("{label}: {e}"))?;
            let (source, frames, message) = match args.modes {
                None => (
                    ViewSource::Equilibrium,
                    vec![frame],
                    "the static equilibrium at the initial rest lengths".to_string(),
                ),
                Some(count) => {
                    let (frames, labels) =
                        view::scene::mode_frames(&model, &geometry, &state, count.max(1), 48);
                    if frames.is_empty() {
                        return Err(format!("{label}: no vibrating mode to animate"));
                    }
                    (ViewSource::Modes, frames, labels.join("\n"))
                }
            };
            let state_word = if source == ViewSource::Modes { "animated" } else { "still" };
            let store = Arc::new(FrameStore::new(frames.len(), status(state_word, &message)));
            frames.iter().for_each(|f| store.push(f));
            let scene_json = geometry.scene_json(&model, &state.poses, source, &label);
            serve(args.port, scene_json, store, &stop, args.serve_for, &format!("{label}: {message}"))
        }
        Target::Bag(path) => {
            if args.modes.is_some() {
                return Err(input_error("--modes is for a scene target".into()));
            }
            let given = match &args.scene {
                Some(p) => Some((load(p)?, p.display().to_string())),
                None => None,
            };
            let bag = view::bag::read_bag(&path, given.as_ref().map(|(m, l)| (m, l.as_str())), args.fps)
                .map_err(input_error)?;
            let geometry = ViewGeometry::new(&bag.model);
            let message = match &bag.cut_short {
                Some(why) => format!(
                    "the bag is cut short; read up to t = {:.3} s ({why})",
                    bag.frames.last().map_or(0.0, |f| f.time)
                ),
                None => String::new(),
            };
            if !message.is_empty() {
                eprintln!("warning: {}: {message}", path.display());
            }
            let store = Arc::new(FrameStore::new(bag.frames.len(), status("recorded", &message)));
            bag.frames.iter().for_each(|f| store.push(f));
            let poses = tensegrity::State::initial(&bag.model).poses;
            let scene_json = geometry.scene_json(&bag.model, &poses, ViewSource::Bag, &bag.label);
            let what = format!(
                "{}: {} recorded steps, {} frames over {:.3} s",
                path.display(),
                bag.steps,
                bag.frames.len(),
                bag.frames.last().map_or(0.0, |f| f.time) - bag.frames[0].time
            );
            serve(args.port, scene_json, store, &stop, args.serve_for, &what)
        }
        Target::Node(prefix) => live(&args, &prefix, stop),
    }
}

fn status(state: &str, message: &str) -> view::ViewStatus {
    view::ViewStatus { state: state.into(), message: message.into() }
}

/// Binds, prints the address and serves until `serve_for` passes (or forever).
fn serve(
    port: u16,
    scene_json: String,
    store: Arc<FrameStore>,
    stop: &Arc<AtomicBool>,
    serve_for: Option<f64>,
    what: &str,
) -> Result<(), String> {
    let server = ViewServer::bind(port, scene_json, store).map_err(|e| input_error(e.to_string()))?;
    say!("{what}");
    say!("viewer at {} (Ctrl-C to stop)", server.url());
    if let Some(s) = serve_for {
        let stop = stop.clone();
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_secs_f64(s));
            stop.store(true, Ordering::Relaxed);
        });
    }
    server.serve_until(stop);
    Ok(())
}

#[cfg(feature = "shm")]
fn live(args: &ViewArgs, prefix: &str, stop: Arc<AtomicBool>) -> Result<(), String> {
    use tensegrity::io::shm::ShmObserver;
    if args.modes.is_some() {
        return Err(input_error("--modes is for a scene target".into()));
    }
    let Some(scene) = &args.scene else {
        return Err(input_error(format!(
            "node:{prefix}: give the scene the node runs with --scene FILE (the node sends names, not geometry)"
        )));
    };
    let model = load(scene)?;
    let timeout = Duration::from_secs_f64(args.timeout);
    let observer = ShmObserver::connect(prefix, timeout).map_err(|e| {
        input_error(format!(
            "node:{prefix}: no node serves shared memory there within {:.1} s ({e}); start one with `tensegrity_node FILE` (its transports must include shm, as they do by default)",
            args.timeout
        ))
    })?;
    let structure =
        observer.structure(timeout.max(Duration::from_secs(2))).map_err(|e| format!("node:{prefix}: {e}"))?;
    view::live::check_structure(&model, &structure, prefix).map_err(input_error)?;
    let geometry = ViewGeometry::new(&model);
    let capacity = (60.0 * view::live::LIVE_RATE_HZ) as usize;
    let store = Arc::new(FrameStore::new(capacity, status("waiting", "waiting for the node's first state")));
    let poses = tensegrity::State::initial(&model).poses;
    let scene_json = geometry.scene_json(
        &model,
        &poses,
        ViewSource::Node,
        &format!("node {prefix} ({})", scene.display()),
    );
    let server =
        ViewServer::bind(args.port, scene_json, store.clone()).map_err(|e| input_error(e.to_string()))?;
    say!("node {prefix}: scene '{}', over shared memory", structure.scene_name);
    say!("viewer at {} (Ctrl-C to stop)", server.url());
    if let Some(s) = args.serve_for {
        let stop = stop.clone();
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_secs_f64(s));
            stop.store(true, Ordering::Relaxed);
        });
    }
    // the page is served from a thread of its own; the shared-memory ports stay on this one
    let serving = {
        let stop = stop.clone();
        std::thread::spawn(move || server.serve_until(&stop))
    };
    let why = view::live::follow(&model, &geometry, &observer, &store, &stop);
    let lost = !stop.load(Ordering::Relaxed);
    if lost {
        eprintln!("error: {why}; the page keeps the frames it has (Ctrl-C to stop)");
    }
    let _ = serving.join();
    if lost {
        return Err(format!("node:{prefix}: the node stopped while it was viewed"));
    }
    Ok(())
}

#[cfg(not(feature = "shm"))]
fn live(_: &ViewArgs, prefix: &str, _: Arc<AtomicBool>) -> Result<(), String> {
    Err(input_error(format!(
        "node:{prefix}: this binary was built without shared memory (rebuild with the default features: cargo build --release)"
    )))
}
