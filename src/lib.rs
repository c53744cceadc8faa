//! # tensegrity
//!
//! Multibody simulation of clustered tensegrity structures: struts are rigid bodies whose poses are
//! the generalized coordinates, cables are massless, tension-only, elastic and damped, and a
//! *clustered* (sliding) cable runs through frictionless pulleys on several bodies with one tension
//! along its whole route.
//!
//! Data flow (one evaluation):
//!
//! ```text
//!  scene file (TOML) --scene::load--> Model (constant)      State (time, poses, velocities,
//!                                       |                          rest lengths, reactions)
//!                                       v                            |
//!       kinematics: poses -> point positions r, Jacobians J, d(J^T f)/dq, d(rdot)/dq
//!                                       |
//!       forces: gravity + cables (L, g = dL/dq, T, Q = -T g, K, C) ; constraints: Phi, Phi_q
//!                                       |
//!       solve: form finding, Newton equilibrium, quasi-static deployment path
//! ```
//!
//! Units are SI throughout (m, kg, s, N, rad). World frame: z up. Rotations are body-to-world.
//! The physics never touches a transport: ROS 2 and shared memory live under `io` behind the
//! `ros2` and `shm` features.

pub mod assembly;
pub mod constraints;
pub mod control;
pub mod error;
pub mod evaluate;
pub mod forces;
pub mod io;
pub mod kinematics;
pub mod machine;
pub mod model;
pub mod plot;
pub mod randomize;
pub mod report;
pub mod scene;
pub mod sensors;
pub mod sim;
pub mod solve;
pub mod state;
pub mod study;
pub mod testing;

pub use error::{SceneError, SolveError};
pub use evaluate::Workspace;
pub use model::Model;
pub use state::State;
