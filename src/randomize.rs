//! Seeded randomization of scene parameters: takes a model as written and its `[randomize]`
//! declarations (`RandomParameter`), gives the model with every declared parameter drawn from
//! its distribution and the list of draws (`Draw`). The same seed gives the same model to the
//! bit; the draws are made in declaration order, element by element, from one PCG64 generator
//! (`rand_pcg::Pcg64`) seeded with the seed.
//!
//! - `ea`, `damping`, `mass` and `pulley_friction` draw a factor on the value as written (a
//!   body's inertia scales with its mass; a cable's pulleys share one factor);
//! - `rest_length` draws an offset, m, on the initial rest length.

use rand::SeedableRng;
use rand_distr::{Distribution, LogNormal, Normal, Uniform};
use rand_pcg::Pcg64;

pub use crate::model::{Draw, Parameter, RandomizationRun};

use crate::model::{BodyId, Model};

/// A distribution of draws.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DrawDistribution {
    /// Uniform on `[low, high)`.
    Uniform {
        /// Lower bound.
        low: f64,
        /// Upper bound (> low).
        high: f64,
    },
    /// Normal with `mean` and standard deviation `sigma` (> 0).
    Normal {
        /// Mean.
        mean: f64,
        /// Standard deviation.
        sigma: f64,
    },
    /// `exp` of a normal with `mean` and `sigma` (> 0): positive.
    LogNormal {
        /// Mean of the logarithm.
        mean: f64,
        /// Standard deviation of the logarithm.
        sigma: f64,
    },
}

impl DrawDistribution {
    /// The smallest value a draw takes in practice: the lower bound, or six standard deviations
    /// below the mean (0 for lognormal).
    pub fn practical_minimum(&self) -> f64 {
        match *self {
            DrawDistribution::Uniform { low, .. } => low,
            DrawDistribution::Normal { mean, sigma } => mean - 6.0 * sigma,
            DrawDistribution::LogNormal { .. } => 0.0,
        }
    }

    /// One draw from `rng`.
    fn sample(&self, rng: &mut Pcg64) -> f64 {
        match *self {
            DrawDistribution::Uniform { low, high } => {
                Uniform::new(low, high).expect("low < high, checked").sample(rng)
            }
            DrawDistribution::Normal { mean, sigma } => {
                Normal::new(mean, sigma).expect("sigma > 0").sample(rng)
            }
            DrawDistribution::LogNormal { mean, sigma } => {
                LogNormal::new(mean, sigma).expect("sigma > 0").sample(rng)
            }
        }
    }
}

/// One declared randomization: a parameter of some elements (cables, or bodies for `mass`) from
/// a distribution.
#[derive(Debug, Clone, PartialEq)]
pub struct RandomParameter {
    /// Which parameter.
    pub parameter: Parameter,
    /// Cable indices (body indices for `Mass`), in declaration order.
    pub elements: Vec<usize>,
    /// The distribution of each element's factor or offset.
    pub distribution: DrawDistribution,
}

/// The scene's randomization: a seed and the declarations (none: the model as written).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Randomization {
    /// Seed of the draws.
    pub seed: u64,
    /// The declarations, in scene order.
    pub parameters: Vec<RandomParameter>,
}

/// Applies `randomization` to `model` (built as written) with `seed`: each declared element's
/// parameter drawn in order (module docs). Returns the draws; the model's `randomized` keeps
/// them too.
pub fn apply(model: &mut Model, randomization: &Randomization, seed: u64) -> Vec<Draw> {
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut draws = Vec::new();
    for p in &randomization.parameters {
        for &e in &p.elements {
            // a factor stays positive (checked with six standard deviations to spare: a draw
            // below that is one in a billion, and is held at 1e-9)
            let drawn = p.distribution.sample(&mut rng);
            let drawn = if p.parameter.is_factor() { drawn.max(1e-9) } else { drawn };
            let (element, written, value) = match p.parameter {
                Parameter::AxialStiffness => {
                    let c = &mut model.cables[e];
                    let written = c.axial_stiffness;
                    c.axial_stiffness *= drawn;
                    (model.cable_names[e].clone(), written, c.axial_stiffness)
                }
                Parameter::Damping => {
                    let c = &mut model.cables[e];
                    let written = c.damping;
                    c.damping *= drawn;
                    (model.cable_names[e].clone(), written, c.damping)
                }
                Parameter::Mass => {
                    let b = &mut model.bodies[e];
                    let written = b.mass;
                    b.mass *= drawn;
                    b.inertia *= drawn;
                    // a lighter node takes a proportionally smaller share of its members'
                    // consistent coupling, so that the mass matrix stays positive definite
                    if drawn < 1.0 {
                        for coupling in
                            model.mass_couplings.iter_mut().filter(|c| c.ends.contains(&BodyId(e)))
                        {
                            coupling.coefficient *= drawn;
                        }
                    }
                    (b.name.clone(), written, b.mass)
                }
                Parameter::RestLength => {
                    let written = model.initial_rest_lengths[e];
                    model.initial_rest_lengths[e] += drawn;
                    (model.cable_names[e].clone(), written, model.initial_rest_lengths[e])
                }
                Parameter::PulleyFriction => {
                    let f = model.cables[e].friction.expect("checked: a cable with friction");
                    let mu = &mut model.pulley_friction[f].mu;
                    let written = mu[0];
                    for m in mu.iter_mut() {
                        *m *= drawn;
                    }
                    (model.cable_names[e].clone(), written, mu[0])
                }
            };
            draws.push(Draw { parameter: p.parameter, element, drawn, written, value });
        }
    }
    draws
}
