//! The edge between the physics and the outside world: takes a `Model` and `NodeParams`, gives
//! a running node (`launch`). Its rooms:
//! - `msg` (wire structs: flat serde copies of the `msg/` package, usable without middleware)
//!   and `schemas` (their ROS definitions, for bags and the Python kit);
//! - `topics` (the one topic table: names, types, QoS, inputs), `commands` (command checks and
//!   limits), `sink` (what a transport's outgoing side sees: `NodeSink`, `NodeView`, stats);
//! - `node` (the transport-free core, its parameters and the loop that runs it with transports);
//! - the transports, behind cargo features: `ros2` (DDS) and `shm` (shared memory), and `python`
//!   (the in-process Python extension `tensegrity._native`, which needs `shm`'s payloads);
//! - `record` (bags: the recorder, offline runs, replay, the MCAP reader and writer);
//! - `view` (the browser viewer: its HTTP server, and frames of a scene, a bag or a running node).
//!
//! Nothing outside this module, `testing` and the binaries imports a transport crate.

pub mod commands;
pub mod msg;
pub mod node;
pub mod record;
pub mod schemas;
pub mod sink;
pub mod topics;

#[cfg(feature = "ros2")]
pub mod ros2;
#[cfg(feature = "shm")]
pub mod shm;

#[cfg(feature = "python")]
pub mod python;
pub mod view;

use crate::io::node::params::{NodeParams, TransportKind};
use crate::io::node::runner::{SimNode, Transport};
use crate::io::node::{CoreError, NodeCore};
use crate::model::Model;

/// Why the node could not start.
#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    /// The simulation could not start.
    #[error(transparent)]
    Core(#[from] CoreError),
    /// A transport could not start (which one, and why).
    #[error("{transport}: {reason}")]
    Transport {
        /// The transport's name.
        transport: &'static str,
        /// Why.
        reason: String,
    },
}

/// Builds the node for `model`: its core from `params`, then every transport in
/// `params.transports` (in that order), and publishes the start-up outputs on all of them.
pub fn launch(model: Model, params: NodeParams) -> Result<SimNode, LaunchError> {
    let core = NodeCore::new(model, params)?;
    launch_core(core)
}

/// Like `launch`, around a core built by the caller (e.g. around a simulator with other settings).
/// With `params.record`, a bag recorder (`record::BagRecorder`) is served last.
pub fn launch_core(core: NodeCore) -> Result<SimNode, LaunchError> {
    launch_core_with(core, Vec::new())
}

/// Like `launch_core`, with `extra` transports served after those of `params.transports` (the
/// test kit's in-process channel, `testing`); it is an error only when there is none at all.
pub fn launch_core_with(core: NodeCore, extra: Vec<Box<dyn Transport>>) -> Result<SimNode, LaunchError> {
    let params = core.params().clone();
    let mut transports = params
        .transports
        .iter()
        .map(|kind| build_transport(*kind, &core, &params))
        .collect::<Result<Vec<_>, _>>()?;
    transports.extend(extra);
    if transports.is_empty() {
        return Err(LaunchError::Transport {
            transport: "none",
            reason: "no transport to serve: this binary was built without the features ros2 and shm \
                     (rebuild with the default features: cargo build --release)"
                .into(),
        });
    }
    if let Some(dir) = &params.record {
        let recorder = record::BagRecorder::for_node(&core, dir)
            .map_err(|e| LaunchError::Transport { transport: "record", reason: e.to_string() })?;
        transports.push(Box::new(recorder));
    }
    Ok(SimNode::new(core, transports))
}

/// One transport of kind `kind` for `core`, or why it cannot be built.
fn build_transport(
    kind: TransportKind,
    core: &NodeCore,
    params: &NodeParams,
) -> Result<Box<dyn Transport>, LaunchError> {
    let fail = |reason: String| LaunchError::Transport { transport: kind.name(), reason };
    let _ = core;
    match kind {
        #[cfg(feature = "ros2")]
        TransportKind::Dds => Ok(Box::new(ros2::DdsTransport::new(params).map_err(|e| fail(e.to_string()))?)),
        #[cfg(feature = "shm")]
        TransportKind::Shm => Ok(Box::new(
            shm::ShmTransport::new(core.simulator().model(), params).map_err(|e| fail(e.to_string()))?,
        )),
        #[allow(unreachable_patterns)]
        other => {
            let _ = params;
            Err(fail(format!(
                "not built into this binary (rebuild with the default features, cargo build --release, \
                 or --features {})",
                other.feature()
            )))
        }
    }
}
