//! Invariant: once running, a simulation step allocates no memory — generalized-alpha and
//! symplectic Euler, dense (prism3: LU, and the joints' Schur complement for Euler) and sparse
//! (tower: supernodal LDL^T of the symmetric part, and LU), RK4 and Dormand-Prince, and
//! error-controlled steps (generalized-alpha on prism3 and the tower, Dormand-Prince: sub-steps,
//! refused attempts and the error estimate), with joints, sliding cables, damping and actuation.
//! A counting global allocator watches the stepping thread.

// A global allocator can only be written with `unsafe`; it forwards to `System` unchanged.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::Integrator;
use tensegrity::solve::linear::LinearBackend;

struct Counting;
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
thread_local!(static WATCHING: Cell<bool> = const { Cell::new(false) });

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if WATCHING.with(|w| w.get()) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if WATCHING.with(|w| w.get()) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations_per_run(scene: &str, settings: SimSettings) -> usize {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes").join(scene);
    let model = tensegrity::scene::load(&path).unwrap();
    let mut sim = Simulator::new(model, settings).unwrap();
    for _ in 0..5 {
        sim.step().unwrap(); // warm-up: first factorizations size their storage
    }
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    WATCHING.with(|w| w.set(true));
    for _ in 0..100 {
        sim.step().unwrap();
    }
    WATCHING.with(|w| w.set(false));
    ALLOCATIONS.load(Ordering::Relaxed) - before
}

#[test]
fn stepping_allocates_nothing() {
    let ga = |linear| SimSettings {
        dt: 1e-3,
        integrator: Integrator::GeneralizedAlpha { rho_inf: 0.8 },
        linear,
        ..Default::default()
    };
    let euler = |linear| SimSettings {
        dt: 5e-4,
        integrator: Integrator::SymplecticEuler,
        linear,
        ..Default::default()
    };
    let explicit = |integrator, dt| SimSettings { dt, integrator, ..Default::default() };
    let controlled =
        |integrator| SimSettings { dt: 1e-3, integrator, tolerance: Some(1e-6), ..Default::default() };
    for (scene, settings, what) in [
        ("prism3.toml", explicit(Integrator::Rk4, 1e-3), "RK4"),
        ("prism3.toml", explicit(Integrator::DormandPrince, 1e-3), "Dormand-Prince"),
        ("prism3.toml", controlled(Integrator::DormandPrince), "Dormand-Prince, error-controlled"),
        (
            "prism3.toml",
            controlled(Integrator::GeneralizedAlpha { rho_inf: 0.8 }),
            "generalized-alpha, error-controlled",
        ),
        (
            "tower.toml",
            controlled(Integrator::GeneralizedAlpha { rho_inf: 0.8 }),
            "generalized-alpha, error-controlled, tower",
        ),
        ("prism3.toml", ga(LinearBackend::Dense), "generalized-alpha, dense"),
        ("prism3.toml", euler(LinearBackend::Dense), "symplectic Euler, dense"),
        ("tower.toml", ga(LinearBackend::Sparse), "generalized-alpha, sparse"),
        ("tower.toml", euler(LinearBackend::Sparse), "symplectic Euler, sparse"),
        ("tower.toml", ga(LinearBackend::SparseLu), "generalized-alpha, sparse LU only"),
        ("tower.toml", euler(LinearBackend::SparseLu), "symplectic Euler, sparse LU only"),
    ] {
        let n = allocations_per_run(scene, settings);
        assert_eq!(n, 0, "{scene} with {what}: {n} allocations in 100 steps");
    }
}
