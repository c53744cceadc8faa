//! Solvers: form finding (rest lengths from a prestressed geometry), quasi-static equilibrium
//! and deployment (with continuation past limit points), natural modes, time integration and
//! their linear algebra.

pub mod continuation;
pub mod deploy;
pub mod dynamics;
pub mod formfind;
pub mod linear;
pub mod modes;
pub mod stability;
pub mod statics;
