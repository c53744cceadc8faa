//! Force elements: takes a route's point kinematics and a cable's material, gives the cable's
//! generalized force, tangent stiffness and damping (`cable`, the classical and sliding cable
//! element), and a contact sphere's normal and friction force against a ground with their tangents
//! (`contact`), two bars' capsules colliding (`collision`), and rotational damping at joints
//! (`joint_damping`), and Coulomb friction at a clustered cable's pulleys (`pulley`). Gravity and the sum over elements are the evaluation stage's (`crate::evaluate`);
//! assembly into coordinates is `crate::assembly`'s.

pub mod cable;
pub mod collision;
pub mod contact;
pub mod joint_damping;
pub mod pulley;
pub mod winch;
