//! `tensegrity generate prism|tower|tbar|atwood|sixbar`: writes a generated scene as TOML (checked
//! as `check` would check it).

use std::path::PathBuf;

use tensegrity::scene::{self, generate};

use crate::output::*;

use clap::Subcommand;

#[derive(Subcommand)]
pub enum GenerateKind {
    /// Regular n-strut prism on pinned supports.
    Prism {
        /// Number of struts.
        #[arg(long, default_value_t = 3)]
        n: usize,
        /// Cluster the top ring into one actuated cable.
        #[arg(long)]
        cluster: bool,
        /// Side-string prestress, N.
        #[arg(long, allow_hyphen_values = true, default_value_t = 100.0)]
        prestress: f64,
        /// The nodal (finite-element) form: struts as elastic members of this EA (N) between
        /// point masses, instead of rigid bars.
        #[arg(long, allow_hyphen_values = true)]
        nodal_strut_ea: Option<f64>,
        /// With --nodal-strut-ea: each strut's consistent mass matrix (a uniform bar's inertia)
        /// instead of half its mass lumped on each end.
        #[arg(long, requires = "nodal_strut_ea")]
        consistent_mass: bool,
    },
    /// Tower of stacked prisms with clustered side cables.
    Tower {
        /// Struts per stage.
        #[arg(long, default_value_t = 3)]
        n: usize,
        /// Number of stages.
        #[arg(long, default_value_t = 3)]
        stages: usize,
    },
    /// Planar clustered T-bar.
    Tbar {
        /// Skelton's pin-jointed T-bar: mast and cross bar as two half-bars each, ball-jointed at
        /// the hub, and the two upper strings separate (the rigid twin of the nodal form).
        #[arg(long)]
        hinged_hub: bool,
        /// The nodal (finite-element) form of the hinged T-bar: the four half-bars as elastic
        /// members of this EA (N) meeting at one hub node.
        #[arg(long, allow_hyphen_values = true)]
        nodal_strut_ea: Option<f64>,
        /// With --nodal-strut-ea: each half-bar's consistent mass matrix (a uniform bar's
        /// inertia) instead of half its mass lumped on each end.
        #[arg(long, requires = "nodal_strut_ea")]
        consistent_mass: bool,
    },
    /// Elastic Atwood machine.
    Atwood {
        /// First mass, kg.
        #[arg(long, allow_hyphen_values = true, default_value_t = 2.0)]
        m1: f64,
        /// Second mass, kg.
        #[arg(long, allow_hyphen_values = true, default_value_t = 1.0)]
        m2: f64,
    },
    /// Six-bar tensegrity robot standing on the ground, with a winch that rolls it over.
    Sixbar {
        /// Friction coefficient of the ground.
        #[arg(long, allow_hyphen_values = true, default_value_t = 0.8)]
        mu: f64,
        /// A winch on every cable and no schedule (the bundled sixbar_rover, for controllers).
        #[arg(long)]
        all_winches: bool,
        /// Robots on the one ground, on a square grid 3 m apart, names prefixed rK_ (for
        /// measuring cost against size).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=1000))]
        robots: u16,
    },
}

/// The members' mass matrix `--consistent-mass` asks for.
fn mass_matrix(consistent: bool) -> scene::MassMatrixSpec {
    if consistent {
        scene::MassMatrixSpec::Consistent
    } else {
        scene::MassMatrixSpec::Lumped
    }
}

/// Runs `generate`, to `out` or standard output.
pub fn run(kind: GenerateKind, out: Option<PathBuf>) -> Result<(), String> {
    let spec = match kind {
        GenerateKind::Prism { n, cluster, prestress, nodal_strut_ea, consistent_mass } => {
            if n < 3 {
                return Err("a prism needs n >= 3".into());
            }
            generate::prism(&generate::PrismParams {
                n,
                cluster_top_ring: cluster,
                side_prestress: prestress,
                deploy_shortening: if cluster { 0.1 } else { 0.0 },
                nodal_strut_ea,
                nodal_mass_matrix: mass_matrix(consistent_mass),
                ..Default::default()
            })
        }
        GenerateKind::Tower { n, stages } => {
            if n < 3 || stages < 1 {
                return Err("a tower needs n >= 3 and stages >= 1".into());
            }
            generate::tower(&generate::TowerParams { n, stages, ..Default::default() })
        }
        GenerateKind::Tbar { hinged_hub, nodal_strut_ea, consistent_mass } => {
            generate::tbar(&generate::TbarParams {
                hinged_hub,
                nodal_strut_ea,
                nodal_mass_matrix: mass_matrix(consistent_mass),
                ..Default::default()
            })
        }
        GenerateKind::Atwood { m1, m2 } => {
            generate::atwood(&generate::AtwoodParams { m1, m2, ..Default::default() })
        }
        GenerateKind::Sixbar { mu, all_winches, robots } => generate::sixbar(&generate::SixbarParams {
            mu,
            all_winches,
            robots: robots.into(),
            ..Default::default()
        }),
    };
    // a generator's arguments are scene fields: refuse what `check` would refuse
    let label = format!("<generated {}>", spec.name);
    scene::build_model(&spec, &label, None).map_err(|e| format!("cannot generate: {e}"))?;
    let text = format!("# generated by `tensegrity generate`\n{}", scene::to_toml(&spec));
    match out {
        Some(p) => std::fs::write(&p, text).map_err(|e| format!("{}: {e}", p.display()))?,
        None => emit(&text),
    }
    Ok(())
}
