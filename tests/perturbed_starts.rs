//! Invariant: from a bundled scene's equilibrium, disturbed by random rotations of up to 30 degrees
//! and displacements of up to 20 % of the structure's size (rest lengths unchanged), statics comes
//! back to an equilibrium with the same energy, or to another one of lower energy with no negative
//! stiffness (the report names its potential energy, so a user sees which one it is); never to a
//! saddle, never with a false claim.

use nalgebra::DVector;
use proptest::prelude::*;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::solve::statics::StaticSolver;
use tensegrity::state::retract;
use tensegrity::{Model, State};

fn equilibrium(name: &str) -> (Model, State, f64) {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes").join(name);
    let model = tensegrity::scene::load(&path).unwrap();
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    StaticSolver::new(&model).equilibrate(&model, &mut state, &mut ws, &model.solver).unwrap();
    evaluate(&model, &state, &mut ws, Tangents::None);
    let energy = ws.energies.elastic + ws.energies.gravitational;
    (model, state, energy)
}

fn disturbed_start_returns(name: &str, seed: &[f64]) -> Result<(), TestCaseError> {
    let (model, eq, energy) = equilibrium(name);
    let size = tensegrity::solve::statics::body_size(&model);
    let mut state = eq.clone();
    // per body: translations up to 0.2 size, rotations up to 30 degrees (local coordinates)
    let mut dq = DVector::zeros(model.dof_count);
    for b in &model.bodies {
        for c in 0..b.dof_count {
            let rotational = b.basis.column(c).fixed_rows::<3>(3).norm() > 0.0;
            let amplitude = if rotational { 30f64.to_radians() } else { 0.2 * size };
            let k = b.dof_offset + c;
            dq[k] = amplitude * seed[k % seed.len()] / 3f64.sqrt();
        }
    }
    retract(&model, &mut state.poses, &dq, 1.0);
    state.multipliers.fill(0.0);
    let mut ws = Workspace::new(&model);
    let r = StaticSolver::new(&model).equilibrate(&model, &mut state, &mut ws, &model.solver);
    let r = r.map_err(|e| TestCaseError::fail(format!("{name}: no equilibrium from {dq:?}: {e:?}")))?;
    evaluate(&model, &state, &mut ws, Tangents::None);
    let found = r.potential_energy;
    prop_assert!(
        (found - (ws.energies.elastic + ws.energies.gravitational)).abs() <= 1e-12 * found.abs().max(1.0)
    );
    prop_assert_eq!(r.negative_modes, 0, "{}: ended on a saddle: {:?}", name, r);
    let scale = energy.abs().max(1e-6);
    prop_assert!(
        (found - energy).abs() <= 1e-6 * scale || found < energy,
        "{}: ended at energy {} J, the bundled equilibrium has {} J",
        name,
        found,
        energy
    );
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 100, .. ProptestConfig::default() })]

    #[test]
    fn prism3_comes_back_from_disturbed_starts(seed in prop::collection::vec(-1.0f64..1.0, 15)) {
        disturbed_start_returns("prism3.toml", &seed)?;
    }

    #[test]
    fn tbar_comes_back_from_disturbed_starts(seed in prop::collection::vec(-1.0f64..1.0, 15)) {
        disturbed_start_returns("tbar.toml", &seed)?;
    }

    #[test]
    fn tower_comes_back_from_disturbed_starts(seed in prop::collection::vec(-1.0f64..1.0, 45)) {
        disturbed_start_returns("tower.toml", &seed)?;
    }
}
