//! `tensegrity generate prism|tower|tbar|atwood|sixbar`: writes a generated scene as TOML (checked
//! as `check` would check it).

use std::path::PathBuf;

use tensegrity::scene::generate::Generator;

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

/// Runs `generate`, to `out` or standard output.
pub fn run(kind: GenerateKind, out: Option<PathBuf>) -> Result<(), String> {
    let generator = match kind {
        GenerateKind::Prism { n, cluster, prestress, nodal_strut_ea, consistent_mass } => {
            Generator::Prism { n, cluster, prestress, nodal_strut_ea, consistent_mass }
        }
        GenerateKind::Tower { n, stages } => Generator::Tower { n, stages },
        GenerateKind::Tbar { hinged_hub, nodal_strut_ea, consistent_mass } => {
            Generator::Tbar { hinged_hub, nodal_strut_ea, consistent_mass }
        }
        GenerateKind::Atwood { m1, m2 } => Generator::Atwood { m1, m2 },
        GenerateKind::Sixbar { mu, all_winches, robots } => {
            Generator::Sixbar { mu, all_winches, robots: robots.into() }
        }
    };
    let text = generator.toml()?;
    match out {
        Some(p) => std::fs::write(&p, text).map_err(|e| format!("{}: {e}", p.display()))?,
        None => emit(&text),
    }
    Ok(())
}
