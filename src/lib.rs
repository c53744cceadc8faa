//! # tensegrity
//!
//! Multibody simulation of clustered tensegrity structures and robots: struts are rigid bodies
//! (or, in nodal models, elastic members between point masses) whose poses are the generalized
//! coordinates; cables are massless, tension-only, elastic and damped; a *clustered* (sliding)
//! cable runs through pulleys on several bodies with one tension along its whole route where the
//! pulleys are frictionless, and keeps the capstan bound across each one where they are not.
//! Bodies may stand on grounds (compliant contact with Coulomb friction) and struts may collide;
//! actuators move rest lengths, ideally or as winch motors; sensors read the state with noise,
//! delay and dropout.
//!
//! Data flow (one evaluation, then the solvers and the simulator):
//!
//! ```text
//!  scene file (TOML) --scene::load--> Model (constant)      State (time, poses, velocities,
//!                                       |                          rest lengths, reactions,
//!                                       v                          winches, pulley material)
//!       kinematics: poses -> point positions r, Jacobians J, d(J^T f)/dq, d(rdot)/dq
//!                                       |
//!       forces: gravity, cables and members (clustered, pulley friction, winches, buckling),
//!       ground contact, strut collision, joint and Rayleigh damping: Q, K, C ; joints: Phi, Phi_q
//!                                       |
//!       solve: form finding, statics (Newton, KKT, stability), quasi-static deployment
//!       (continuation past limit points), modes, dynamics (generalized-alpha, explicit)
//!                                       |
//!       sim: Simulator (sub-steps, guards, error control, energy account) -> study, report, plot
//! ```
//!
//! Units are SI throughout (m, kg, s, N, rad). World frame: z up. Rotations are body-to-world.
//! The physics never touches a transport: ROS 2, shared memory and the Python binding live under
//! `io` behind the `ros2`, `shm` and `python` features. Where each part lives, and the checklists
//! for adding a force element, a sensor, a topic or a subcommand: `docs/architecture.md`.

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
pub mod progress;
pub mod randomize;
pub mod render;
pub mod report;
pub mod scene;
pub mod sensors;
pub mod sim;
pub mod solve;
pub mod state;
pub mod study;
pub mod summary;
pub mod task;
pub mod testing;

pub use error::{SceneError, SolveError};
pub use evaluate::Workspace;
pub use model::Model;
pub use state::State;
