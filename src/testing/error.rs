//! Why the kit could not start or serve a simulator (`KitError`).

use std::time::Duration;

/// Why the kit could not start or serve a simulator.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum KitError {
    /// The scene could not be read or is invalid.
    #[error("scene: {0}")]
    Scene(String),
    /// A parameter is unknown, out of range or does not fit the scene.
    #[error("parameter: {0}")]
    Params(String),
    /// A transport could not start, or the node was not discoverable in time.
    #[error("transport: {0}")]
    Transport(String),
    /// The simulation could not start, or a step failed (the node then holds the last good state
    /// until `reset`).
    #[error("physics: {0}")]
    Physics(String),
    /// The node refused the request (a rejected command, stepping while playing), with its reason.
    #[error("refused: {0}")]
    Refused(String),
    /// No answer within the time allowed.
    #[error("timed out after {0:?} waiting for {1}")]
    Timeout(Duration, String),
    /// The node's loop is no longer running.
    #[error("the simulator has stopped")]
    Stopped,
}
