//! Seeded randomization of scene parameters (`tensegrity::randomize`, `[randomize]`): draws
//! that pass a Kolmogorov-Smirnov test against their declared distributions, the same seed
//! giving the same model to the bit, the physics using the drawn values, a randomized run that
//! replays bit for bit, and careless tables.

mod common;

use tensegrity::model::Model;
use tensegrity::randomize::Parameter;

/// The hanging load (`common::hanging_load`: 10 kg on a rope of EA 1e5 N) with the rope damped
/// at 50 N s/m, and `randomize` appended.
fn hanging(randomize: &str) -> String {
    common::hanging_load().replacen("rest_length = 1.0\n", "rest_length = 1.0\ndamping = 50.0\n", 1)
        + randomize
}

const DECLARED: &str = r#"
[randomize]
seed = SEED
[[randomize.parameters]]
parameter = "ea"
distribution = "uniform"
low = 0.8
high = 1.2
[[randomize.parameters]]
parameter = "mass"
elements = ["load"]
distribution = "normal"
mean = 1.0
sigma = 0.05
[[randomize.parameters]]
parameter = "rest_length"
distribution = "normal"
mean = 0.0
sigma = 0.002
[[randomize.parameters]]
parameter = "damping"
distribution = "lognormal"
mean = 0.0
sigma = 0.3
"#;

fn drawn(seed: u64) -> Model {
    common::model_from_toml(&hanging(&DECLARED.replace("SEED", &seed.to_string())))
}

/// `Phi(x)` of the standard normal, by `erfc` (Numerical Recipes' Chebyshev fit, |error| < 1.2e-7).
fn normal_cdf(x: f64) -> f64 {
    let z = x.abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.26551223
        + t * (1.00002368
            + t * (0.37409196
                + t * (0.09678418
                    + t * (-0.18628806
                        + t * (0.27886807
                            + t * (-1.13520398 + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277))))))));
    let erfc = t * poly.exp();
    if x >= 0.0 {
        1.0 - 0.5 * erfc
    } else {
        0.5 * erfc
    }
}

/// The Kolmogorov-Smirnov p-value of `samples` against `cdf`: `D = sup |F_n - F|`, and
/// `p = 2 sum_k (-1)^(k-1) exp(-2 k^2 n D^2)` (asymptotic).
fn ks_p_value(mut samples: Vec<f64>, cdf: impl Fn(f64) -> f64) -> f64 {
    samples.sort_by(f64::total_cmp);
    let n = samples.len() as f64;
    let d = samples
        .iter()
        .enumerate()
        .map(|(i, x)| {
            let f = cdf(*x);
            (f - i as f64 / n).max((i + 1) as f64 / n - f)
        })
        .fold(0.0, f64::max);
    let lambda = (n.sqrt() + 0.12 + 0.11 / n.sqrt()) * d;
    let p: f64 =
        (1..100).map(|k| 2.0 * (-1f64).powi(k - 1) * (-2.0 * (k * k) as f64 * lambda * lambda).exp()).sum();
    p.clamp(0.0, 1.0)
}

#[test]
fn draws_pass_a_kolmogorov_smirnov_test_against_their_distributions() {
    let models: Vec<Model> = (0..2000).map(drawn).collect();
    let drawn_of = |p: Parameter| -> Vec<f64> {
        models.iter().map(|m| m.randomized.iter().find(|d| d.parameter == p).unwrap().drawn).collect()
    };
    type Cdf = Box<dyn Fn(f64) -> f64>;
    let tests: [(Parameter, Cdf); 4] = [
        (Parameter::AxialStiffness, Box::new(|x: f64| ((x - 0.8) / 0.4).clamp(0.0, 1.0))),
        (Parameter::Mass, Box::new(|x: f64| normal_cdf((x - 1.0) / 0.05))),
        (Parameter::RestLength, Box::new(|x: f64| normal_cdf(x / 0.002))),
        (Parameter::Damping, Box::new(|x: f64| normal_cdf(x.ln() / 0.3))),
    ];
    for (p, cdf) in tests {
        let p_value = ks_p_value(drawn_of(p), cdf);
        assert!(p_value > 0.01, "{}: p = {p_value}", p.name());
    }
    // and against a wrong distribution the test does fail: it has the power to tell
    let p_value = ks_p_value(drawn_of(Parameter::AxialStiffness), |x| ((x - 0.8) / 0.5).clamp(0.0, 1.0));
    assert!(p_value < 1e-6, "a wrong uniform passed: p = {p_value}");
}

#[test]
fn the_model_uses_the_drawn_values_and_a_seed_gives_the_same_model_to_the_bit() {
    let m = drawn(42);
    let written = common::model_from_toml(&hanging(""));
    let rope = &m.cables[0];
    let draw = |p: Parameter| m.randomized.iter().find(|d| d.parameter == p).unwrap().clone();
    let ea = draw(Parameter::AxialStiffness);
    assert_eq!((ea.element.as_str(), ea.written), ("rope", 1e5));
    assert_eq!(rope.axial_stiffness, 1e5 * ea.drawn);
    assert_eq!(m.bodies[1].mass, 10.0 * draw(Parameter::Mass).drawn);
    assert_eq!(m.initial_rest_lengths[0], 1.0 + draw(Parameter::RestLength).drawn);
    assert_eq!(rope.damping, 50.0 * draw(Parameter::Damping).drawn);
    assert_eq!(m.randomized.len(), 4, "the fixed ceiling has no mass to draw");
    assert!(written.randomized.is_empty());
    // the same seed: the same model; another: another
    let again = drawn(42);
    assert_eq!(format!("{:?}", again.cables), format!("{:?}", m.cables));
    assert_eq!(again.bodies[1].mass.to_bits(), m.bodies[1].mass.to_bits());
    assert_ne!(drawn(43).cables[0].axial_stiffness, rope.axial_stiffness);
    // the physics hangs the drawn load on the drawn rope
    let sim = tensegrity::sim::Simulator::at_equilibrium(m.clone(), Default::default()).unwrap();
    let t = sim.workspace().cables[0].tension;
    assert!((t - m.bodies[1].mass * 9.81).abs() < 1e-6 * t, "{t}");
    let stretch = sim.workspace().cables[0].length - m.initial_rest_lengths[0];
    assert!((stretch - t * m.initial_rest_lengths[0] / rope.axial_stiffness).abs() < 1e-12);
}

#[test]
fn a_randomized_run_replays_bit_for_bit() {
    let scene = common::scratch("randomize").join("hanging.toml");
    std::fs::write(&scene, hanging(&DECLARED.replace("SEED", "9"))).unwrap();
    let dir = common::scratch("randomize").join("bag");
    let _ = std::fs::remove_dir_all(&dir);
    let cli = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_tensegrity")).args(args).output().unwrap()
    };
    let out = cli(&[
        "deploy",
        scene.to_str().unwrap(),
        "--dynamic",
        "--duration",
        "0.2",
        "--record",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = cli(&["replay", dir.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("identical"), "{text}");
    let check = cli(&["check", scene.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&check.stdout);
    assert!(text.contains("randomized: ea of rope drawn"), "{text}");
}

#[test]
fn careless_randomization_is_refused_naming_the_field() {
    for (table, field, reason) in [
        ("parameter = \"stiffness\"\ndistribution = \"uniform\"\nlow = 0.9\nhigh = 1.1", "parameter", "not ea"),
        ("parameter = \"ea\"\ndistribution = \"gamma\"", "distribution", "not uniform"),
        ("parameter = \"ea\"\ndistribution = \"uniform\"\nlow = 1.1\nhigh = 0.9", "high", "above low"),
        ("parameter = \"ea\"\ndistribution = \"uniform\"\nhigh = 0.9", "low", "needs low"),
        ("parameter = \"ea\"\ndistribution = \"normal\"\nmean = 1.0\nsigma = 0.0", "sigma", "positive"),
        ("parameter = \"ea\"\ndistribution = \"normal\"\nmean = 1.0\nsigma = 0.5", "distribution", "positive"),
        ("parameter = \"ea\"\ndistribution = \"uniform\"\nlow = nan\nhigh = 1.0", "low", "finite"),
        ("parameter = \"ea\"\nelements = [\"chain\"]\ndistribution = \"uniform\"\nlow = 0.9\nhigh = 1.1", "elements", "unknown cable"),
        ("parameter = \"mass\"\nelements = [\"ceiling\"]\ndistribution = \"uniform\"\nlow = 0.9\nhigh = 1.1", "elements", "no mass"),
        ("parameter = \"pulley_friction\"\nelements = [\"rope\"]\ndistribution = \"uniform\"\nlow = 0.9\nhigh = 1.1", "elements", "no pulley friction"),
        ("parameter = \"rest_length\"\ndistribution = \"uniform\"\nlow = -2.0\nhigh = 0.0", "distribution", "would reach"),
        ("parameter = \"ea\"\ndistribution = \"uniform\"\nlow = 0.9\nhigh = 1.1\nspread = 2.0", "randomize", "spread"),
    ] {
        let text = hanging(&format!("[randomize]\n[[randomize.parameters]]\n{table}\n"));
        let err = tensegrity::scene::from_toml(&text, "careless.toml").expect_err(table).to_string();
        assert!(err.contains("careless.toml"), "{err}");
        assert!(err.contains(field), "{table}: {err}");
        assert!(err.contains(reason), "{table}: {err}");
    }
}

struct Structures(Vec<tensegrity::io::msg::Structure>);

impl tensegrity::io::sink::NodeSink for Structures {
    fn publish(
        &mut self,
        topic: tensegrity::io::topics::Topic,
        view: &tensegrity::io::sink::NodeView<'_>,
    ) -> Result<(), tensegrity::io::sink::PublishError> {
        use tensegrity::io::sink::TopicMessage;
        if let Some(TopicMessage::Structure(s)) = TopicMessage::build(topic, view)? {
            self.0.push(s);
        }
        Ok(())
    }
    fn step_request_done(
        &mut self,
        _ticket: u64,
        _result: tensegrity::io::msg::SimResult,
        _view: &tensegrity::io::sink::NodeView<'_>,
    ) {
    }
}

#[test]
fn a_scene_randomized_per_reset_draws_each_episode_anew_and_the_same_episodes_again() {
    use tensegrity::io::node::{params::NodeParams, NodeCore};
    let per_reset = DECLARED.replace("SEED", "5").replace("seed = 5\n", "seed = 5\nper = \"reset\"\n");
    let model = common::model_from_toml(&hanging(&per_reset));
    let episodes = || {
        let params = NodeParams { start_paused: true, start_from_equilibrium: true, ..NodeParams::default() };
        let mut core = NodeCore::new(model.clone(), params).unwrap();
        let mut sink = Structures(Vec::new());
        core.start(&mut sink);
        let mut eas = vec![core.simulator().model().cables[0].axial_stiffness];
        for _ in 0..3 {
            core.reset(&mut sink);
            eas.push(core.simulator().model().cables[0].axial_stiffness);
            assert!(core.fault().is_none());
            // at rest on the episode's own rope and load
            let m = core.simulator().model();
            let t = core.simulator().workspace().cables[0].tension;
            assert!((t - m.bodies[1].mass * 9.81).abs() < 1e-6 * t);
        }
        (eas, sink.0)
    };
    let (eas, structures) = episodes();
    assert_eq!(eas[0], model.cables[0].axial_stiffness, "the start is episode 0");
    assert!(eas.windows(2).all(|w| w[0] != w[1]), "each reset draws anew: {eas:?}");
    // each episode's structure names its draws
    let published: Vec<(u32, f64)> =
        structures.iter().map(|s| (s.randomize_episode, s.randomized_value[0])).collect();
    assert_eq!(published, (0..4).map(|k| (k, eas[k as usize])).collect::<Vec<_>>());
    assert!(structures.iter().all(|s| s.randomize_seed == 5 && s.randomized_parameter[0] == "ea"));
    // episode k is the scene drawn with seed 5 + k, the same in another node
    assert_eq!(episodes().0, eas);
    let third = common::model_from_toml(&hanging(&DECLARED.replace("SEED", "7")));
    assert_eq!(third.cables[0].axial_stiffness, eas[2]);
    // drawn once per run, a reset keeps the draw
    let mut core =
        NodeCore::new(drawn(5), NodeParams { start_paused: true, ..NodeParams::default() }).unwrap();
    let before = core.simulator().model().cables[0].axial_stiffness;
    core.reset(&mut Structures(Vec::new()));
    assert_eq!(core.simulator().model().cables[0].axial_stiffness, before);
}

#[test]
fn a_seeded_reset_draws_its_episode_from_the_seed_whatever_came_before() {
    use tensegrity::io::node::{params::NodeParams, NodeCore};
    // drawn once per run (no `per = "reset"`): a seeded reset draws anyway, from its seed
    let model = drawn(5);
    let params = NodeParams { start_paused: true, start_from_equilibrium: true, ..NodeParams::default() };
    let mut core = NodeCore::new(model.clone(), params).unwrap();
    let mut sink = Structures(Vec::new());
    core.start(&mut sink);
    let ea = |core: &NodeCore| core.simulator().model().cables[0].axial_stiffness;
    let mut seeded = Vec::new();
    for seed in [9, 9, 10, 9] {
        core.reset_seeded(Some(seed), &mut sink);
        assert!(core.fault().is_none());
        seeded.push(ea(&core));
    }
    assert!(seeded[0] == seeded[1] && seeded[1] != seeded[2] && seeded[3] == seeded[0], "{seeded:?}");
    // the seed's draw is the scene's with that seed
    let by_seed = common::model_from_toml(&hanging(&DECLARED.replace("SEED", "9")));
    assert_eq!(seeded[0], by_seed.cables[0].axial_stiffness);
    // published with its seed, episode 0
    let last = sink.0.last().unwrap();
    assert_eq!((last.randomize_seed, last.randomize_episode, last.randomized_value[0]), (9, 0, seeded[0]));
    // an unseeded reset of a scene drawn once per run starts the same episode over
    core.reset(&mut sink);
    assert_eq!(ea(&core), seeded[3]);
    assert_ne!(ea(&core), model.cables[0].axial_stiffness);
}
