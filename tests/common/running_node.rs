//! A `SimNode` running its real-time loop on a background thread, for DDS tests and benches.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use tensegrity::io::params::NodeParams;
use tensegrity::io::ros2::{NodeStats, SimNode};

/// The node's thread and its stop flag.
pub struct RunningNode {
    stop: Arc<AtomicBool>,
    handle: JoinHandle<NodeStats>,
}

impl RunningNode {
    /// Builds the node for `model` with `params` and runs it until `stop` is called.
    pub fn start(model: tensegrity::Model, params: NodeParams) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let handle = std::thread::spawn(move || {
            let mut node = SimNode::new(model, params).unwrap();
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
