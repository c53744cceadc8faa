//! Invariant: the elastic Atwood machine (m1 = 2 kg, m2 = 1 kg, k = EA/L0 = 1000 N/m, g = 9.81)
//! follows its closed form. Started just taut, the tension is `T*(1 - cos(omega t))` with
//! `T* = 2 m1 m2 g/(m1 + m2) = 13.08 N` and `omega = sqrt(k (1/m1 + 1/m2)) = 38.7298 rad/s`;
//! generalized-alpha (rho_inf = 1) at dt = 1e-4 s matches it within 2e-4 T* over 0.5 s, about
//! 3 periods (measured 2.2e-5 T*: the method's phase error (omega h)^2 omega t / 12). Started slack, both masses fall freely with
//! zero tension until the cable tightens at `t_c = sqrt(slack / g)`.

mod common;

use common::*;
use tensegrity::scene::generate::{atwood, AtwoodParams};
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::Integrator;

const G: f64 = 9.81;

#[test]
fn just_taut_atwood_tension_follows_one_minus_cosine() {
    let model = model_of(&atwood(&AtwoodParams::default()));
    let settings = SimSettings {
        dt: 1e-4,
        integrator: Integrator::GeneralizedAlpha { rho_inf: 1.0 },
        ..Default::default()
    };
    let mut sim = Simulator::new(model, settings).unwrap();
    let (m1, m2, k) = (2.0, 1.0, 1000.0);
    let t_star = 2.0 * m1 * m2 * G / (m1 + m2);
    let omega = (k * (1.0 / m1 + 1.0 / m2)).sqrt();
    assert!((t_star - 13.08).abs() < 1e-9 && (omega - 38.729833).abs() < 1e-6);
    let mut worst: f64 = 0.0;
    for _ in 0..5000 {
        sim.step().unwrap();
        let t = sim.state().time;
        let tension = sim.workspace().cables[0].tension;
        worst = worst.max((tension - t_star * (1.0 - (omega * t).cos())).abs());
    }
    eprintln!("atwood worst tension error {worst:.3e} N = {:.3e} T*", worst / t_star);
    assert!(worst <= 2e-4 * t_star, "worst tension error {worst} N ({:.2e} of T*)", worst / t_star);
}

#[test]
fn slack_atwood_falls_freely_until_the_cable_tightens() {
    let slack = 0.02;
    let model = model_of(&atwood(&AtwoodParams { initial_stretch: -slack, ..Default::default() }));
    let settings = SimSettings { dt: 1e-4, ..Default::default() };
    let mut sim = Simulator::new(model, settings).unwrap();
    let t_c = (slack / G).sqrt();
    let z0 = sim.state().poses[1].position.z;
    let mut tightened = None;
    for _ in 0..1000 {
        sim.step().unwrap();
        let t = sim.state().time;
        let tension = sim.workspace().cables[0].tension;
        if t < t_c - 1e-4 {
            assert_eq!(tension, 0.0, "tension before the cable tightens at t = {t}");
            for b in [1, 2] {
                let z = sim.state().poses[b].position.z;
                assert!((z - (z0 - 0.5 * G * t * t)).abs() < 1e-9, "free fall of body {b} at t = {t}");
            }
        } else if tension > 0.0 && tightened.is_none() {
            tightened = Some(t);
        }
    }
    let t_tight = tightened.expect("the cable tightens");
    assert!((t_tight - t_c).abs() <= 2e-4, "tightened at {t_tight}, expected {t_c}");
}
