//! Recording runs into bags and replaying them: takes the node core's outputs (`BagRecorder`, a
//! `Transport` of the node's loop, so it sees exactly what the core published and applied) or an
//! offline run's (`offline::OfflineRun`, the CLI's `deploy --dynamic`, drives the same core;
//! `PathPublisher` publishes a quasi-static path), gives a rosbag2 bag (`record::bag`) with every published topic, the applied
//! commands on `~/applied_commands` (`tensegrity_msgs/msg/AppliedCommands`) and the run record;
//! takes such a bag back (`replay`) and runs it again with the recorded commands (and resets) at
//! their recorded steps, comparing every recorded message bit for bit.
//!
//! Files: `bag` (the MCAP writer and the streaming reader), `batch` (a recorder's batch of
//! states), `recorder`, `offline`, `replay`, and `run`: the run record (`run_info`, `settings_of`) and the
//! node's bag topics (`node_topics`); this file only gathers them.
//!
//! On the node's thread a step's `/clock` and state topics cost a few hundred nanoseconds: the
//! state's numbers are appended to a batch (`StepBatch`: poses, rest lengths, cable responses,
//! segment lengths, rates, and point positions when the markers go) that is handed to the
//! bag's writer thread every `BATCH_RECORDS` records; that thread builds and serializes their
//! messages (`bag::Compose`). When its queue is full a batch is dropped whole (counted as a
//! publish failure); the structure, the static transforms and the applied commands never are
//! (`droppable`), and they hand the batch over first, so messages keep their order.
//!
//! Each message's MCAP `sequence` is the simulator's step count when it was published (steps
//! since the start, resets included; modulo 2^32), its log time the wall clock for the node and
//! the simulation time for offline runs (a quasi-static path: 1 ms per row).
//!
//! What is reproducible: the same scene, settings and commands at the same steps give the same
//! bits (the physics has no wall-clock, thread-count or hash-order dependence), so a run's
//! real-time overruns, its machine's load and its transports do not matter. `/diagnostics` holds
//! wall-clock figures (real-time factor, overruns) and is recorded but not compared.

pub mod bag;
pub mod batch;
pub mod offline;
pub mod recorder;
pub mod replay;
mod run;

pub use recorder::{BagRecorder, PathPublisher};
pub use replay::{applied_commands, decode_json, replay, Difference, ReplayError, ReplayReport};
pub use run::*;
