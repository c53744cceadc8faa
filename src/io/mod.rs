//! The edge between the physics and the outside world: wire types (flat serde copies of the
//! `msg/` package, usable without any middleware) and, behind the `ros2` and `shm` cargo features,
//! the transports. Nothing outside this module and the binaries imports a transport crate.

pub mod msg;
pub mod node;
pub mod params;

#[cfg(feature = "ros2")]
pub mod ros2;
