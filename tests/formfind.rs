//! Invariant: form finding gives the same rest lengths, or the same refusal, whether it uses the
//! dense SVD or the sparse saddle-point solves (every bundled scene, generated prisms and towers,
//! free-floating and planar structures, and specifications that over-determine, under-determine
//! or contradict equilibrium), and its sparse path costs a factor whose size grows linearly with
//! the structure (prisms of 100 to 999 struts), so `check` stays fast on large scenes.

use std::path::Path;

mod common;
use common::{knot_between_cables, model_from_toml};

use tensegrity::evaluate::{evaluate_forces, Workspace};
use tensegrity::scene::generate::{prism, tower, PrismParams, TowerParams};
use tensegrity::scene::{build_model, load, SceneSpec};
use tensegrity::solve::formfind::{find_rest_lengths_with, FormFindingMethod, RestLengthSpec};
use tensegrity::{Model, State};

/// Tensions (N) and lengths (m) of every cable at the initial geometry and rest lengths.
fn start_tensions(model: &Model) -> (Vec<f64>, Vec<f64>) {
    let state = State::initial(model);
    let mut ws = Workspace::for_forces(model);
    evaluate_forces(model, &state, &mut ws);
    (ws.cables.iter().map(|c| c.tension).collect(), ws.cables.iter().map(|c| c.length).collect())
}

/// The text of a refusal up to its first number (numbers may differ in the last digits).
fn gist(reason: &str) -> &str {
    reason.split(|c: char| c.is_ascii_digit()).next().unwrap_or(reason)
}

/// Dense and sparse agree: the same rest lengths to 1e-9 (relative), or the same refusal.
/// Returns whether they succeeded.
fn agree(model: &Model, specs: &[RestLengthSpec], label: &str) -> bool {
    let dense = find_rest_lengths_with(model, specs, FormFindingMethod::Dense);
    let sparse = find_rest_lengths_with(model, specs, FormFindingMethod::Sparse);
    match (&dense, &sparse) {
        (Ok(d), Ok(s)) => {
            assert!(d.unknowns == 0 || (d.dense && !s.dense), "{label}: methods not as asked");
            for (c, (a, b)) in d.rest_lengths.iter().zip(&s.rest_lengths).enumerate() {
                assert!(
                    (a - b).abs() <= 1e-9 * a.abs().max(1e-3),
                    "{label}: cable {} rest length dense {a} vs sparse {b}",
                    model.cable_names[c]
                );
            }
            true
        }
        (Err((cd, rd)), Err((cs, rs))) => {
            assert_eq!(cd, cs, "{label}: blamed cables differ: '{rd}' vs '{rs}'");
            assert_eq!(gist(rd), gist(rs), "{label}: refusals differ: '{rd}' vs '{rs}'");
            false
        }
        _ => panic!("{label}: dense {dense:?} but sparse {sparse:?}"),
    }
}

/// Specification variants built from a model's own equilibrium tensions: every cable free,
/// every cable at its tension (over-determined but consistent), one target and the rest free,
/// one force density, half the rest lengths given, and two contradicting targets.
fn variants(model: &Model) -> Vec<(String, Vec<RestLengthSpec>)> {
    let (tensions, lengths) = start_tensions(model);
    let nc = tensions.len();
    let l0 = &model.initial_rest_lengths;
    let taut: Vec<usize> = (0..nc).filter(|&c| tensions[c] > 1e-6).collect();
    let mut out = vec![
        ("all free".to_string(), vec![RestLengthSpec::Free; nc]),
        (
            "all at their tension".to_string(),
            (0..nc).map(|c| RestLengthSpec::Prestress(tensions[c].max(0.0))).collect(),
        ),
        (
            "half given".to_string(),
            (0..nc)
                .map(|c| if c % 2 == 0 { RestLengthSpec::Given(l0[c]) } else { RestLengthSpec::Free })
                .collect(),
        ),
    ];
    if let Some(&c0) = taut.first() {
        let mut one = vec![RestLengthSpec::Free; nc];
        one[c0] = RestLengthSpec::Prestress(tensions[c0]);
        out.push(("one target".into(), one.clone()));
        one[c0] = RestLengthSpec::ForceDensity(tensions[c0] / lengths[c0]);
        out.push(("one force density".into(), one));
    }
    if taut.len() >= 2 {
        let mut two = vec![RestLengthSpec::Free; nc];
        two[taut[0]] = RestLengthSpec::Prestress(tensions[taut[0]]);
        two[taut[1]] = RestLengthSpec::Prestress(2.0 * tensions[taut[1]] + 1.0);
        out.push(("contradicting targets".into(), two));
    }
    out
}

fn check_model(model: &Model, name: &str) -> usize {
    let mut solved = 0;
    for (label, specs) in variants(model) {
        if agree(model, &specs, &format!("{name}: {label}")) {
            solved += 1;
        }
    }
    solved
}

#[test]
fn dense_and_sparse_agree_on_bundled_scenes() {
    let mut solved = 0;
    for dir in ["config/scenes", "config/examples"] {
        let mut paths: Vec<_> = std::fs::read_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join(dir))
            .expect("scene directory")
            .map(|e| e.expect("entry").path())
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .collect();
        paths.sort();
        for path in paths {
            let model = load(&path).unwrap_or_else(|e| panic!("{e}"));
            solved += check_model(&model, &path.display().to_string());
        }
    }
    assert!(solved >= 10, "only {solved} variants had an equilibrium: the comparison tests little");
}

#[test]
fn dense_and_sparse_agree_on_generated_structures() {
    let mut specs: Vec<SceneSpec> = Vec::new();
    for n in 3..=7 {
        for cluster in [false, true] {
            specs.push(prism(&PrismParams { n, cluster_top_ring: cluster, ..Default::default() }));
        }
    }
    for (n, stages) in [(3, 2), (3, 3), (4, 2)] {
        specs.push(tower(&TowerParams { n, stages, ..Default::default() }));
    }
    // held by nothing: rigid-body motions make the equilibrium equations redundant
    let mut free = prism(&PrismParams::default());
    free.name = "free prism".into();
    free.joints.clear();
    let template = free.cables[0].clone();
    for i in 0..3 {
        let mut c = template.clone();
        c.name = format!("bottom{i}");
        c.route = vec![format!("bar0_{i}.a"), format!("bar0_{}.a", (i + 1) % 3)];
        (c.prestress, c.rest_length, c.force_density) = (None, None, None);
        free.cables.push(c);
    }
    specs.push(free);
    let mut solved = 0;
    for spec in &specs {
        let model = build_model(spec, &spec.name, None).unwrap_or_else(|e| panic!("{e}"));
        solved += check_model(&model, &spec.name);
    }
    assert!(solved >= 3 * specs.len(), "only {solved} variants solved");
}

/// A knot between two collinear ropes (rest lengths given, so that the scene builds; the tests
/// ask form finding again with other specifications).
fn rope(gravity: f64) -> Model {
    knot_between_cables(1.0, 1.0, 1000.0, gravity, "rest_length = 0.9", "rest_length = 0.9")
}

#[test]
fn both_methods_refuse_the_same_impossible_specifications() {
    use RestLengthSpec::{Free, Given, Prestress};
    // no load: any equal tension balances, so free ropes are undetermined, and one target fixes both
    let model = rope(0.0);
    assert!(!agree(&model, &[Free, Free], "undetermined rope"));
    let err = find_rest_lengths_with(&model, &[Free, Free], FormFindingMethod::Sparse).unwrap_err();
    assert!(err.1.contains("cannot determine the tensions of cables west, east"), "{}", err.1);
    assert!(agree(&model, &[Prestress(50.0), Free], "rope with one target"));
    let found = find_rest_lengths_with(&model, &[Prestress(50.0), Free], FormFindingMethod::Sparse).unwrap();
    let east = found.rest_lengths[1];
    assert!((east - 1000.0 / 1050.0).abs() < 1e-12, "east rest length {east}");
    // contradicting targets: both report the nearest equilibrium and blame a cable
    assert!(!agree(&model, &[Prestress(50.0), Prestress(80.0)], "rope with two targets"));
    let err = find_rest_lengths_with(&model, &[Prestress(50.0), Prestress(80.0)], FormFindingMethod::Sparse)
        .unwrap_err();
    assert!(err.1.contains("nearest equilibrium has 65.0"), "{}", err.1);
    // a given slack rope on one side leaves the other nothing to pull against: zero tension
    assert!(agree(&model, &[Given(1.5), Free], "one slack given rope"));
    // with gravity, horizontal ropes cannot hold the knot
    let model = rope(-9.81);
    assert!(!agree(&model, &[Free, Free], "sagging rope"));
    let err = find_rest_lengths_with(&model, &[Free, Free], FormFindingMethod::Sparse).unwrap_err();
    assert!(err.1.contains("not an equilibrium"), "{}", err.1);
}

#[test]
fn a_rope_that_must_push_is_refused_by_both() {
    // a knot standing on one rope anchored below it, gravity down: the rope would have to push
    let text = r#"
name = "push"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "ground"
kind = "fixed"
points = { below = [0.0, 0.0, -1.0] }
[[bodies]]
name = "knot"
kind = "node"
mass = 1.0
position = [0.0, 0.0, 0.0]
[[cables]]
name = "down"
route = ["knot", "ground.below"]
ea = 1000.0
rest_length = 0.9
"#;
    let model = model_from_toml(text);
    assert!(!agree(&model, &[RestLengthSpec::Free], "pushing rope"));
    let err = find_rest_lengths_with(&model, &[RestLengthSpec::Free], FormFindingMethod::Sparse).unwrap_err();
    assert_eq!(err.0, tensegrity::solve::formfind::Blame::Cable(0));
    assert!(err.1.contains("push"), "{}", err.1);
}

/// Entries of the sparse factor per strut of a clustered n-prism, and the unknowns.
fn factor_per_strut(n: usize) -> f64 {
    let spec =
        prism(&PrismParams { n, cluster_top_ring: true, deploy_shortening: 0.0, ..Default::default() });
    let model = build_model(&spec, "<prism>", None).unwrap_or_else(|e| panic!("{e}"));
    let mut specs = vec![RestLengthSpec::Free; model.cables.len()];
    specs[0] = RestLengthSpec::Prestress(100.0);
    let found =
        find_rest_lengths_with(&model, &specs, FormFindingMethod::Auto).unwrap_or_else(|e| panic!("{e:?}"));
    assert!(!found.dense, "n = {n}: Auto should take the sparse path");
    // the model's own rest lengths came from the same specification (side strings at 100 N)
    let (tensions, _) = {
        let mut m = model.clone();
        m.initial_rest_lengths = found.rest_lengths.clone();
        start_tensions(&m)
    };
    assert!((tensions[0] - 100.0).abs() < 1e-6, "n = {n}: target tension {}", tensions[0]);
    found.factor_entries as f64 / n as f64
}

#[test]
fn sparse_form_finding_cost_grows_linearly_with_the_prism() {
    let small = factor_per_strut(100);
    let large = factor_per_strut(999);
    assert!(
        large <= 1.5 * small,
        "factor entries per strut grew from {small:.1} (100 struts) to {large:.1} (999 struts)"
    );
}

#[test]
fn the_singular_value_decomposition_reconstructs_its_matrix() {
    use nalgebra::DMatrix;
    use tensegrity::solve::linear::ThinSvd;
    // form finding and `study`'s alignment use faer's SVD: nalgebra 0.35's reconstructed the
    // form-finding matrix of a 4-strut prism with half its rest lengths given (20 x 14) with an
    // error of 9.5e-4 and refused a valid scene (`dense_and_sparse_agree_on_generated_structures`
    // caught it); the 3 x 3 is the alignment matrix reported in dimforge/nalgebra#1172
    let h = DMatrix::from_row_slice(
        3,
        3,
        &[
            0.24777976656646927,
            0.5496207895780494,
            -0.7403583528727136,
            0.5832953614864118,
            -0.38015695826419854,
            -0.03392366142812886,
            -0.3738110622901052,
            0.359160059894174,
            -0.09620293929130566,
        ],
    );
    for a in [h.clone(), h.transpose(), DMatrix::from_fn(20, 14, |i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0)]
    {
        let svd = ThinSvd::new(&a).expect("converges");
        let back = &svd.u * DMatrix::from_diagonal(&svd.s) * svd.v.transpose();
        assert!((back - &a).amax() < 1e-13 * a.amax(), "reconstruction error");
        assert!(svd.s.iter().zip(svd.s.iter().skip(1)).all(|(a, b)| a >= b), "singular values not sorted");
    }
}

/// The bundled prism3 (pinned bottom ends, side strings at 100 N) set free on a floor with
/// stick-slip friction, under gravity: no pins, a bottom ring of three cables (rest lengths to be
/// found), the bar ends contact spheres of radius 0 (the bottom ones on the floor).
fn prism3_on_the_floor() -> (Model, Vec<RestLengthSpec>) {
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scenes/prism3.toml"))
            .unwrap();
    let mut text: String = text
        .split("[[joints]]")
        .enumerate()
        .map(|(i, part)| {
            if i == 0 {
                part.to_string()
            } else {
                part.split_once("\n\n").map_or(String::new(), |p| p.1.to_string())
            }
        })
        .collect();
    text = text.replace("mass = 2.0\n", "mass = 2.0\ncontact_radius = 0.0\n");
    text = text.replacen("[[bodies]]", "gravity = [0.0, 0.0, -9.81]\n\n[[bodies]]", 1);
    for (i, (a, b)) in
        [("bar0_0.a", "bar0_1.a"), ("bar0_1.a", "bar0_2.a"), ("bar0_2.a", "bar0_0.a")].iter().enumerate()
    {
        text.push_str(&format!(
            "\n[[cables]]\nname = \"bottom{i}\"\nroute = [\"{a}\", \"{b}\"]\nea = 50000.0\n"
        ));
    }
    text.push_str("\n[[grounds]]\nname = \"floor\"\nmu = 0.8\nstiffness = 1e6\nstick_stiffness = 1e5\n");
    let model = model_from_toml(&text);
    let specs = model
        .cable_names
        .iter()
        .map(|n| if n.starts_with("side") { RestLengthSpec::Prestress(100.0) } else { RestLengthSpec::Free })
        .collect();
    (model, specs)
}

#[test]
fn a_prism_standing_on_the_floor_is_form_found_with_the_pinned_prisms_self_stress_and_settles_onto_its_feet()
{
    // Its weight works along the prism's twist mechanism, so no tensions hold it at the sketched
    // pose with its weight: its self-stress is found without the weight (as the pinned prism's,
    // whose pins take what the bottom ring takes here), and statics settles it onto its three
    // feet, which carry the whole weight and stick.
    let (model, specs) = prism3_on_the_floor();
    assert_eq!(model.joints.len(), 0);
    let found = find_rest_lengths_with(&model, &specs, FormFindingMethod::Auto).unwrap();
    assert!(found.settles_under_weight && found.reactions.is_empty());
    let pinned =
        tensegrity::scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scenes/prism3.toml"))
            .unwrap();
    for (c, name) in pinned.cable_names.iter().enumerate() {
        let here = model.cable_names.iter().position(|n| n == name).unwrap();
        let (a, b) = (pinned.initial_rest_lengths[c], found.rest_lengths[here]);
        assert!((a - b).abs() <= 1e-12 * a, "{name}: rest length {b} m on the floor, {a} m pinned");
        assert_eq!(model.initial_rest_lengths[here], b, "{name}: the scene's build form-finds the same");
    }
    // the bottom ring carries, at the sketch, the ring's tension (the self-stress is symmetric)
    let (tensions, _) = start_tensions(&model);
    let ring = tensions[model.cable_names.iter().position(|n| n == "ring").unwrap()];
    for (name, t) in model.cable_names.iter().zip(&tensions) {
        if name.starts_with("bottom") {
            assert!((t - ring).abs() <= 1e-9 * ring, "{name}: {t} N, the ring {ring} N");
        }
    }

    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    let report = tensegrity::solve::statics::StaticSolver::new(&model)
        .equilibrate(&model, &mut state, &mut ws, &model.solver)
        .unwrap();
    assert!(report.stable, "settled on its feet: {report:?}");
    let weight = 3.0 * 2.0 * 9.81;
    let carried: f64 = ws.contacts.iter().map(|c| c.normal_force).sum();
    assert!((carried - weight).abs() <= 1e-9 * weight, "the feet carry {carried} N of {weight} N");
    let feet = tensegrity::report::contact_reports(&model, &ws);
    let stuck: Vec<&str> =
        feet.iter().filter(|c| c.friction_state == "stick").map(|c| c.point.as_str()).collect();
    assert_eq!(stuck, ["bar0_0.a", "bar0_1.a", "bar0_2.a"]);
    // the weight adds to the self-stress: the sides pull a little more than their 100 N
    for (name, c) in model.cable_names.iter().zip(&ws.cables) {
        if name.starts_with("side") {
            assert!(c.tension > 100.0 && c.tension < 110.0, "{name}: {} N", c.tension);
        }
    }
}

#[test]
fn a_block_held_by_a_prestressed_tether_is_form_found_with_its_contact_reactions() {
    // a 1 kg block on a floor (mu 0.5) and a tether to a post 1 m away, prestressed to 2 N: the
    // sketched pose is an equilibrium with the floor's reactions, N = m g and friction 2 N, and
    // statics keeps the block there (it moves by its springs' deflections only)
    let scene = |prestress: f64, ground: &str| {
        format!(
            "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"post\"\nkind = \"fixed\"\npoints = {{ hook = [1.0, 0.0, 0.0] }}\n\
             [[bodies]]\nname = \"block\"\nkind = \"node\"\nmass = 1.0\nposition = [0.0, 0.0, 0.0]\ncontact_radius = 0.0\n\
             [[cables]]\nname = \"tether\"\nroute = [\"block\", \"post.hook\"]\nea = 1000.0\nprestress = {prestress}\n\
             [[grounds]]\nname = \"floor\"\n{ground}\n"
        )
    };
    let stick = "mu = 0.5\nstiffness = 1e5\nstick_stiffness = 1e4";
    let model = model_from_toml(&scene(2.0, stick));
    let found =
        find_rest_lengths_with(&model, &[RestLengthSpec::Prestress(2.0)], FormFindingMethod::Auto).unwrap();
    assert!(!found.settles_under_weight);
    assert_eq!(found.reactions.len(), 1);
    let r = found.reactions[0];
    assert!((r.normal - 9.81).abs() < 1e-9 && (r.friction - 2.0).abs() < 1e-9, "{r:?}");
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    tensegrity::solve::statics::StaticSolver::new(&model)
        .equilibrate(&model, &mut state, &mut ws, &model.solver)
        .unwrap();
    // the friction's spring gives a little: stuck, the tether and the spring share the pull,
    // T = k_t x = EA (1 - x - L0) / L0 with L0 = EA / (EA + 2 N)
    let (ea, k_t) = (1000.0, 1e4);
    let l0 = ea / (ea + 2.0);
    let x = ea * (1.0 - l0) / l0 / (k_t + ea / l0);
    let moved = state.poses[1].position.x;
    // (to 1e-9 m: the block also sinks by m g / k_n = 1e-4 m, which lengthens the tether by
    // 5e-9 m, a term the level closed form leaves out)
    assert!((moved - x).abs() < 1e-9, "the block moved {moved} m toward the post, closed form {x} m");
    assert!(
        (ws.cables[0].tension - k_t * x).abs() < 1e-5,
        "tether at {} N, closed form {} N",
        ws.cables[0].tension,
        k_t * x
    );
    assert!(
        (ws.contacts[0].friction.norm() - ws.cables[0].tension).abs() < 1e-7,
        "friction against the pull"
    );
    assert_eq!(ws.contacts[0].friction_state, tensegrity::forces::contact::FrictionState::Stuck);

    // careless: more pull than the cone holds, a tilted floor, a ground that cannot pull, and
    // a floor without stick_stiffness (no friction at rest): each refused, naming the line
    let refused = |text: &str| {
        let err =
            build_model(&toml::from_str::<SceneSpec>(text).unwrap(), "block.toml", Some(text)).unwrap_err();
        (err.line, err.field.clone(), err.reason.clone())
    };
    let text = scene(6.0, stick);
    let (line, field, reason) = refused(&text);
    assert_eq!(field, "grounds[0].mu");
    assert_eq!(line, text.lines().position(|l| l.starts_with("mu = ")).map(|i| i + 1));
    assert!(
        reason
            .contains("needs 6.000000 N of friction at block on `floor`, beyond its cone mu N = 4.905000 N"),
        "{reason}"
    );
    let (_, field, reason) = refused(&scene(2.0, &format!("normal = [0.0, 0.0, -1.0]\n{stick}")));
    assert_eq!(field, "grounds[0].normal", "{reason}");
    assert!(reason.contains("needs the ground `floor` to pull block down with 9.81"), "{reason}");
    let text = scene(2.0, "mu = 0.5\nstiffness = 1e5");
    let (line, field, reason) = refused(&text);
    assert_eq!(field, "cables[0].prestress", "{reason}");
    assert_eq!(line, text.lines().position(|l| l.starts_with("prestress")).map(|i| i + 1));
    assert!(reason.contains("stick_stiffness"), "{reason}");
}

#[test]
fn a_pinned_prism_that_touches_a_floor_keeps_the_rest_lengths_its_pins_give() {
    // prism3 as bundled (pinned feet, no weight) with its bar ends contact spheres on a floor:
    // its cables and pins hold it without the floor, so the floor takes no reaction and the rest
    // lengths are the bundled scene's, bit for bit
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scenes/prism3.toml");
    let text =
        std::fs::read_to_string(&path).unwrap().replace("mass = 2.0\n", "mass = 2.0\ncontact_radius = 0.0\n")
            + "\n[[grounds]]\nname = \"floor\"\nmu = 0.8\nstiffness = 1e6\nstick_stiffness = 1e5\n";
    let on_floor = model_from_toml(&text);
    let pinned = tensegrity::scene::load(&path).unwrap();
    assert!(on_floor.contact_pairs() > 0);
    assert_eq!(on_floor.initial_rest_lengths, pinned.initial_rest_lengths);
    let specs: Vec<RestLengthSpec> = on_floor
        .cable_names
        .iter()
        .map(|n| if n.starts_with("side") { RestLengthSpec::Prestress(100.0) } else { RestLengthSpec::Free })
        .collect();
    let found = find_rest_lengths_with(&on_floor, &specs, FormFindingMethod::Auto).unwrap();
    assert!(found.reactions.is_empty() && !found.settles_under_weight);
}
