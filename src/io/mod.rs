//! The edge between the physics and the outside world: wire types (flat serde copies of the
//! `msg/` package, usable without any middleware), the transport-free node core and loop, and,
//! behind the `ros2` and `shm` cargo features, the transports. Nothing outside this module and
//! the binaries imports a transport crate.

pub mod bag;
pub mod msg;
pub mod node;
pub mod params;
pub mod record;
pub mod runner;
pub mod schemas;
pub mod testing;

#[cfg(feature = "ros2")]
pub mod ros2;
#[cfg(feature = "shm")]
pub mod shm;

use crate::io::node::{CoreError, NodeCore};
use crate::io::params::{NodeParams, TransportKind};
use crate::io::runner::{SimNode, Transport};
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
            reason: "no transport to serve (parameter transports, features ros2 and shm)".into(),
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
            Err(fail(format!("not built into this binary (rebuild with --features {})", other.feature())))
        }
    }
}
