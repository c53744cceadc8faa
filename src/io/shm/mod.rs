//! The shared-memory transport (feature `shm`, iceoryx2 0.10): takes `NodeParams` and the model,
//! gives `ShmTransport` (the node's zero-copy face in the node's loop, `io::node::runner`) and
//! `ShmClient` (a controller's side, in Rust) and `ShmObserver` (a watcher that the node never
//! waits on or wakes: the live viewer); the payloads are fixed-size `#[repr(C)]` types
//! that the Python client (`python/tensegrity/testing/shm.py`) mirrors with `ctypes`.
//!
//! Services, named under the node's namespace and name like its ROS topics (`<ns>/<node>/...`
//! without the leading slash; `tensegrity_sim/...` by default):
//! - `state` (publish-subscribe, `StateSample`): one sample per published step (the node's
//!   `state_publish_rate`, every step when 0; in lockstep, as the steps are taken);
//! - `structure` (publish-subscribe, `StructureSample`, history 1): names and array order, for
//!   late joiners;
//! - `actuator_commands` (publish-subscribe, `CommandSample`): commands in, checked exactly like
//!   DDS commands (`commands::check_entry`: rejected whole, counted in `StateSample` and
//!   `/diagnostics`), applied at the next step boundary;
//! - `lockstep` (request-response, `LockstepRequest` -> `LockstepResponse`): commands plus a
//!   number of steps in, the state after those steps out; only while the node is paused (like
//!   StepSimulation), requests served one at a time in arrival order;
//! - events `to_node` (controllers notify after sending, and on asking for the structure) and `from_node` (the node notifies
//!   after each state sample, `EVENT_STATE`, and lockstep answer, `EVENT_RESPONSE`), so neither
//!   side busy-spins: after an answer each side polls for at most `NodeParams::shm_spin_us`
//!   (`ShmClient::set_spin`), yielding its core between polls, then blocks on its listener.
//!
//! Capacities (`MAX_BODIES`, `MAX_CABLES`, `MAX_ACTUATORS`, `MAX_CONTACTS`, `MAX_PULLEYS`,
//! `NAME_BYTES`) are compile-time
//! constants checked against the scene at start-up. Dead iceoryx2 nodes (a controller or node
//! killed with SIGKILL) are cleaned up at start and every `CLEANUP_PERIOD`, so their ports do not
//! hold the service's slots. Only one node can serve a namespace: a second fails to start.

mod client;
mod observer;
mod payload;
mod server;
mod service;

pub use client::*;
pub use observer::*;
pub use payload::*;
pub use server::*;
pub use service::*;
