//! A `SimNode` running its real-time loop on a background thread, for DDS tests and benches.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use tensegrity::io::node::NodeStats;
use tensegrity::io::params::{NodeParams, TransportKind};

/// The node's thread and its stop flag.
pub struct RunningNode {
    stop: Arc<AtomicBool>,
    handle: JoinHandle<NodeStats>,
}

impl RunningNode {
    /// Builds the node for `model` with `params`, serving DDS only (parallel tests share the
    /// default shared-memory names, DDS tests do not), and runs it until `stop` is called.
    #[allow(dead_code)]
    pub fn start(model: tensegrity::Model, params: NodeParams) -> Self {
        Self::start_serving(model, NodeParams { transports: vec![TransportKind::Dds], ..params })
    }

    /// Like `start`, serving the transports of `params.transports` as given.
    #[allow(dead_code)]
    pub fn start_serving(model: tensegrity::Model, params: NodeParams) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let handle = std::thread::spawn(move || {
            let mut node = tensegrity::io::launch(model, params).unwrap();
            node.run(&flag);
            node.stats()
        });
        Self { stop, handle }
    }

    /// Stops the loop and returns the node's counters.
    pub fn stop(self) -> NodeStats {
        self.stop.store(true, Ordering::Relaxed);
        self.handle.join().unwrap()
    }
}
