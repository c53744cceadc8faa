//! Solvers: form finding (rest lengths from a prestressed geometry) and quasi-static equilibrium
//! and deployment.

pub mod dynamics;
pub mod formfind;
pub mod linear;
pub mod modes;
pub mod statics;
