//! A `SimNode` running its real-time loop on a background thread, for DDS tests and benches: the
//! test kit's simulator (`tensegrity::testing`) started from parameters given field by field.

use tensegrity::io::node::params::{NodeParams, TransportKind};
use tensegrity::io::sink::NodeStats;
use tensegrity::testing::{SimBuilder, SimUnderTest};

/// The kit's handle; stops on `stop` or drop.
pub struct RunningNode(SimUnderTest);

impl RunningNode {
    /// Builds the node for `model` with `params`, serving DDS only (parallel tests share the
    /// default shared-memory names, DDS tests do not), and runs it until `stop` is called.
    #[allow(dead_code)]
    pub fn start(model: tensegrity::Model, params: NodeParams) -> Self {
        Self::start_serving(model, NodeParams { transports: vec![TransportKind::Dds], ..params })
    }

    /// Like `start`, serving the transports of `params.transports` as given; returns once they
    /// are discoverable.
    #[allow(dead_code)]
    pub fn start_serving(model: tensegrity::Model, params: NodeParams) -> Self {
        Self(SimBuilder::model(model).node_params(params).start().unwrap_or_else(|e| panic!("{e}")))
    }

    /// Stops the loop and returns the node's counters.
    pub fn stop(self) -> NodeStats {
        self.0.stop().stats
    }
}
