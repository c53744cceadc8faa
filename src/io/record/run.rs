//! The run record and the node's bag topics: takes a model, the simulator's settings and the
//! node's parameters, gives the `RunInfo` a bag carries (kind, scene, settings) and reads the
//! settings back (`settings_of`), and the topics a node run records (`node_topics`).

use crate::io::node::params::NodeParams;
use crate::io::record::bag::{BagOptions, RunInfo, TopicSpec};
use crate::io::topics::TopicQos;
use crate::io::topics::{applied_commands_topic, topic_name, topic_type, Topic};
use crate::model::Model;
use crate::sim::SimSettings;
use crate::solve::dynamics::{Integrator, NewtonSettings};
use crate::solve::linear::LinearBackend;

/// `RunInfo` key of the run's kind: `KIND_NODE`, `KIND_DYNAMIC` or `KIND_QUASI_STATIC`.
pub const KEY_KIND: &str = "kind";
/// A node run.
pub const KIND_NODE: &str = "node";
/// `tensegrity deploy --dynamic`.
pub const KIND_DYNAMIC: &str = "deploy-dynamic";
/// `tensegrity deploy --quasi-static`.
pub const KIND_QUASI_STATIC: &str = "deploy-quasi-static";

/// Where a recorded message's log time comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogTime {
    /// The wall clock (ns since the Unix epoch), as `ros2 bag record` stamps: the node.
    Wall,
    /// The simulation time, ns: offline dynamic runs.
    SimTime,
    /// 1 ms per step of the sequence: quasi-static paths (whose time may go back on a traced
    /// branch).
    Step,
}

fn f64_text(x: f64) -> String {
    // Debug prints the shortest text that parses back to the same bits
    format!("{x:?}")
}

fn linear_name(l: LinearBackend) -> &'static str {
    match l {
        LinearBackend::Dense => "dense",
        LinearBackend::Sparse => "sparse",
        LinearBackend::SparseLu => "sparse-lu",
        LinearBackend::Auto => "auto",
    }
}

/// The run record of a run of `model` with `settings` and the node parameters that decide what
/// the core does and publishes (`params`); `kind` is one of the `KIND_` names.
pub fn run_info(
    kind: &str,
    model: &Model,
    scene_label: &str,
    settings: &SimSettings,
    params: &NodeParams,
) -> RunInfo {
    let mut r = RunInfo::new();
    let mut put = |k: &str, v: String| {
        r.insert(k.to_string(), v);
    };
    put(KEY_KIND, kind.into());
    put("tensegrity_version", env!("CARGO_PKG_VERSION").into());
    put("scene", model.source.to_string());
    put("scene_file", scene_label.into());
    put("scene_name", model.name.clone());
    put("dt", f64_text(settings.dt));
    let (integrator, rho) = match settings.integrator {
        Integrator::GeneralizedAlpha { rho_inf } => ("generalized-alpha", rho_inf),
        Integrator::SymplecticEuler => ("symplectic-euler", params.rho_inf),
        Integrator::Rk4 => ("rk4", params.rho_inf),
        Integrator::DormandPrince => ("dormand-prince", params.rho_inf),
    };
    put("integrator", integrator.into());
    put("rho_inf", f64_text(rho));
    put("tolerance", settings.tolerance.map_or("none".into(), f64_text));
    put("min_dt", f64_text(settings.min_dt));
    put("linear", linear_name(settings.linear).into());
    put("newton_tolerance", f64_text(settings.newton.tolerance));
    put("newton_max_iterations", settings.newton.max_iterations.to_string());
    put("newton_reuse_factorization", settings.newton.reuse_factorization.to_string());
    put("follow_schedule", params.follow_schedule.to_string());
    put("start_from_equilibrium", params.start_from_equilibrium.to_string());
    put("state_publish_rate", f64_text(params.state_publish_rate));
    put("markers_rate", f64_text(params.markers_rate));
    put("command_timeout", f64_text(params.command_timeout));
    put("command_timeout_action", params.command_timeout_action.clone());
    put("frame_id", params.frame_id.clone());
    put("node_name", params.node_name.clone());
    put("namespace", params.namespace.clone());
    r
}

/// Why a run record cannot be run again.
pub(crate) fn record_err(key: &str, why: impl std::fmt::Display) -> String {
    format!("run record: {key}: {why}")
}

/// The simulator settings and node parameters of a run record (the inverse of `run_info`).
pub fn settings_of(run: &RunInfo) -> Result<(SimSettings, NodeParams), String> {
    let get = |k: &str| run.get(k).map(String::as_str).ok_or_else(|| record_err(k, "missing"));
    let num = |k: &str| -> Result<f64, String> { get(k)?.parse::<f64>().map_err(|e| record_err(k, e)) };
    let integrator = Integrator::parse(get("integrator")?, num("rho_inf")?)
        .ok_or_else(|| record_err("integrator", "unknown"))?;
    let linear = match get("linear")? {
        "dense" => LinearBackend::Dense,
        "sparse" => LinearBackend::Sparse,
        "sparse-lu" => LinearBackend::SparseLu,
        "auto" => LinearBackend::Auto,
        other => return Err(record_err("linear", format!("unknown '{other}'"))),
    };
    let newton = NewtonSettings {
        tolerance: num("newton_tolerance")?,
        max_iterations: get("newton_max_iterations")?
            .parse()
            .map_err(|e| record_err("newton_max_iterations", e))?,
        reuse_factorization: get("newton_reuse_factorization")? == "true",
    };
    let tolerance = match get("tolerance")? {
        "none" => None,
        _ => Some(num("tolerance")?),
    };
    let settings =
        SimSettings { dt: num("dt")?, integrator, newton, min_dt: num("min_dt")?, linear, tolerance };
    let mut params = NodeParams {
        node_name: get("node_name")?.into(),
        namespace: get("namespace")?.into(),
        real_time_factor: 0.0,
        start_paused: true,
        newton_tolerance: settings.newton.tolerance,
        ..NodeParams::default()
    };
    for k in [
        "follow_schedule",
        "state_publish_rate",
        "markers_rate",
        "command_timeout",
        "command_timeout_action",
        "frame_id",
    ] {
        params.set(k, get(k)?).map_err(|e| record_err(k, e))?;
    }
    // bags recorded before the option started from the scene's pose
    if let Some(v) = run.get("start_from_equilibrium") {
        params.set("start_from_equilibrium", v).map_err(|e| record_err("start_from_equilibrium", e))?;
    }
    Ok((settings, params))
}

/// The topics a node with `params` publishes for `model`, and the applied commands, as bag
/// topics: the `Topic` each comes from (`None`: applied commands).
pub fn node_topics(params: &NodeParams, model: &Model) -> Vec<(Option<Topic>, TopicSpec)> {
    let mut out = Vec::new();
    for topic in Topic::ALL {
        if (topic == Topic::Markers && params.markers_rate <= 0.0) || !topic.published_by(model) {
            continue;
        }
        if let Some((type_name, qos)) = topic_type(topic) {
            let spec = TopicSpec {
                name: topic_name(topic.name(), &params.private_namespace()),
                type_name: type_name.into(),
                qos,
            };
            out.push((Some(topic), spec));
        }
    }
    let applied = TopicSpec {
        name: applied_commands_topic(&params.private_namespace()),
        type_name: "tensegrity_msgs/msg/AppliedCommands".into(),
        qos: TopicQos { depth: 100, transient_local: false },
    };
    out.push((None, applied));
    out
}

/// The bag options of a node's recording: the defaults with the writer thread in the
/// background (`BagOptions::background`), as the node steps in real time.
pub fn node_bag_options() -> BagOptions {
    BagOptions { background: true, ..BagOptions::default() }
}
