//! Invariant: a malformed scene never panics; it gets a `SceneError` naming the file, the line,
//! the field path and the reason — for every case listed in the mechanics-core issue.

use tensegrity::scene::from_toml;
use tensegrity::SceneError;

const VALID: &str = r#"name = "ok"
gravity = [0.0, 0.0, -9.81]

[[bodies]]
name = "ground"
kind = "fixed"
points = { top = [0.0, 0.0, 2.0], left = [-1.0, 0.0, 2.0] }

[[bodies]]
name = "pole"
kind = "bar"
mass = 1.0
ends = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]

[[bodies]]
name = "box"
kind = "rigid"
mass = 2.0
position = [0.5, 0.0, 0.5]
inertia = [0.1, 0.1, 0.1]
points = { hook = [0.0, 0.0, 0.2] }

[[joints]]
kind = "pin"
a = "pole.a"

[[cables]]
name = "stay"
route = ["ground.top", "pole.b"]
ea = 1000.0
rest_length = 0.9

[[cables]]
name = "sling"
route = ["ground.left", "pole.b", "box.hook"]
ea = 1000.0
rest_length = 2.0
"#;

fn error_of(text: &str) -> SceneError {
    match from_toml(text, "scene.toml") {
        Ok(_) => panic!("accepted a malformed scene:\n{text}"),
        Err(e) => e,
    }
}

fn expect(text: &str, field: &str, line: usize, reason_has: &str) {
    let e = error_of(text);
    assert_eq!(e.file, "scene.toml");
    assert_eq!(e.field, field, "{e}");
    assert_eq!(e.line, Some(line), "{e}");
    assert!(e.reason.contains(reason_has), "reason of '{e}' should mention '{reason_has}'");
    let shown = e.to_string();
    assert!(shown.starts_with(&format!("scene.toml:{line}: {field}: ")), "{shown}");
}

#[test]
fn the_valid_base_scene_is_accepted() {
    let model = from_toml(VALID, "scene.toml").unwrap();
    assert_eq!(model.dof_count, 5 + 6);
    assert_eq!(model.pulley_count(), 1);
}

#[test]
fn missing_mass_is_named() {
    expect(&VALID.replace("mass = 2.0\n", ""), "bodies[2].mass", 15, "missing");
}

#[test]
fn negative_mass_is_named() {
    expect(&VALID.replace("mass = 2.0", "mass = -2.0"), "bodies[2].mass", 18, "positive");
}

#[test]
fn non_positive_ea_is_named() {
    expect(&VALID.replacen("ea = 1000.0", "ea = 0.0", 1), "cables[0].ea", 30, "positive");
    expect(&VALID.replacen("ea = 1000.0", "ea = -5.0", 1), "cables[0].ea", 30, "positive");
}

#[test]
fn non_positive_rest_length_is_named() {
    expect(&VALID.replace("rest_length = 2.0", "rest_length = 0.0"), "cables[1].rest_length", 37, "positive");
    expect(
        &VALID.replace("rest_length = 2.0", "rest_length = -1.0"),
        "cables[1].rest_length",
        37,
        "positive",
    );
}

#[test]
fn route_through_unknown_body_or_point_is_named() {
    expect(
        &VALID.replace("\"box.hook\"]", "\"crate.hook\"]"),
        "cables[1].route",
        35,
        "unknown body in 'crate.hook'",
    );
    expect(&VALID.replace("\"box.hook\"]", "\"box.eye\"]"), "cables[1].route", 35, "no point 'box.eye'");
}

#[test]
fn duplicate_names_are_named() {
    expect(
        &VALID.replace("name = \"box\"", "name = \"pole\""),
        "bodies[2].name",
        16,
        "duplicate body name 'pole'",
    );
    expect(
        &VALID.replace("name = \"sling\"", "name = \"stay\""),
        "cables[1].name",
        34,
        "duplicate cable name 'stay'",
    );
}

#[test]
fn cable_with_fewer_than_two_points_is_named() {
    expect(
        &VALID.replace("route = [\"ground.top\", \"pole.b\"]", "route = [\"pole.b\"]"),
        "cables[0].route",
        29,
        "at least two points",
    );
}

#[test]
fn free_coordinate_without_mass_is_named() {
    expect(
        &VALID.replace("inertia = [0.1, 0.1, 0.1]", "inertia = [0.0, 0.1, 0.1]"),
        "bodies[2].inertia",
        20,
        "needs inertia",
    );
    expect(
        &VALID.replace("inertia = [0.1, 0.1, 0.1]", "inertia = [0.1, 0.1, 0.5]"),
        "bodies[2].inertia",
        20,
        "triangle inequality",
    );
    expect(&VALID.replace("mass = 1.0\nends", "mass = 0.0\nends"), "bodies[1].mass", 12, "positive");
}

#[test]
fn unknown_fields_are_rejected_with_their_line() {
    expect(
        &VALID.replace("ea = 1000.0\nrest_length = 2.0", "ea = 1000.0\nstiffness = 3.0\nrest_length = 2.0"),
        "cables[1].stiffness",
        37,
        "unknown field",
    );
    expect(&VALID.replace("name = \"ok\"", "name = \"ok\"\ncolour = \"red\""), "colour", 2, "unknown field");
}

#[test]
fn wrong_types_and_syntax_errors_carry_their_line() {
    expect(&VALID.replace("mass = 2.0", "mass = \"heavy\""), "bodies[2].mass", 18, "");
    let e = error_of(&VALID.replace("[[cables]]\nname = \"sling\"", "[[cables]\nname = \"sling\""));
    assert_eq!(e.line, Some(33), "{e}");
}

#[test]
fn other_structural_mistakes_are_explained() {
    expect(&VALID.replace("a = \"pole.a\"", "a = \"pole.q\""), "joints[0].a", 25, "unknown point");
    expect(
        &VALID.replace("rest_length = 0.9", "rest_length = 0.9\nprestress = 3.0"),
        "cables[0].prestress",
        32,
        "not both",
    );
    expect(
        &VALID.replace(
            "route = [\"ground.left\", \"pole.b\", \"box.hook\"]",
            "route = [\"ground.left\", \"pole.b\", \"pole.b\"]",
        ),
        "cables[1].route",
        35,
        "twice in a row",
    );
    expect(
        &VALID.replace(
            "ends = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]",
            "ends = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]",
        ),
        "bodies[1].ends",
        13,
        "coincide",
    );
    let prestress_push = VALID.replace("rest_length = 0.9", "prestress = -3.0");
    expect(&prestress_push, "cables[0].prestress", 31, "only pull");
}

#[test]
fn a_missing_file_is_named() {
    let e = tensegrity::scene::load(std::path::Path::new("/nonexistent/scene.toml")).unwrap_err();
    assert_eq!(e.file, "/nonexistent/scene.toml");
    assert!(e.reason.contains("cannot read"));
}

#[test]
fn deployment_ramps_are_checked_against_actuator_limits() {
    let with_actuator = format!(
        "{VALID}\n[[actuators]]\nname = \"w\"\ncable = \"sling\"\nmin_rest_length = 1.5\nmax_rest_length = 2.5\nmax_rate = 0.1\n\n[deployment]\nsteps = 10\n\n[[deployment.ramps]]\nactuator = \"w\"\nduration = 1.0\nrest_length = 1.6\n"
    );
    expect(&with_actuator, "deployment.ramps[0].duration", 51, "max_rate");
    expect(
        &with_actuator.replace("rest_length = 1.6\n", "rest_length = 1.0\n"),
        "deployment.ramps[0].rest_length",
        52,
        "outside",
    );
    expect(
        &with_actuator.replace("actuator = \"w\"", "actuator = \"v\""),
        "deployment.ramps[0].actuator",
        50,
        "unknown actuator",
    );
}

#[test]
fn physics_dt_is_read_and_checked() {
    let model =
        from_toml(&VALID.replace("gravity = ", "physics_dt = 0.002\ngravity = "), "scene.toml").unwrap();
    assert_eq!(model.physics_dt, Some(0.002));
    assert_eq!(from_toml(VALID, "scene.toml").unwrap().physics_dt, None);
    expect(&VALID.replace("gravity = ", "physics_dt = -0.001\ngravity = "), "physics_dt", 2, "positive");
}

/// The hostile inputs of the robustness issue: each once hung `check`, was accepted with values it
/// did not read, or produced non-finite output. Now each is refused at load, naming line and field.
#[test]
fn hostile_numbers_and_shapes_are_refused_at_load() {
    let pole_ends = "ends = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]";
    // (text, field, a string on the line the error must point at, reason)
    let cases: Vec<(String, &str, &str, &str)> = vec![
        (
            VALID.replace(pole_ends, "ends = [[1e308, 0.0, 0.0], [0.0, 0.0, 1.0]]"),
            "bodies[1].ends",
            "1e308",
            "within +-1e6 m",
        ),
        (
            VALID.replace(pole_ends, "ends = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]"),
            "bodies[1].ends",
            "ends =",
            "exactly 2 end points",
        ),
        (
            VALID.replace(pole_ends, "ends = [[0.0, 0.0, 0.0, 7.0], [0.0, 0.0, 1.0]]"),
            "bodies[1].ends",
            "ends =",
            "exactly 3 numbers",
        ),
        (
            VALID.replace("gravity = [0.0, 0.0, -9.81]", "gravity = [0.0, 0.0, -9.81, 1.0]"),
            "gravity",
            "gravity",
            "exactly 3 numbers",
        ),
        (
            VALID.replace("gravity = [0.0, 0.0, -9.81]", "gravity = [1e308, 0.0, -9.81]"),
            "gravity",
            "gravity",
            "within +-1000 m/s^2",
        ),
        (
            VALID.replace(
                "position = [0.5, 0.0, 0.5]",
                "position = [0.5, 0.0, 0.5]\nrotation = [0.0, 0.0, 0.1, 0.2]",
            ),
            "bodies[2].rotation",
            "rotation",
            "exactly 3 numbers",
        ),
        (VALID.replacen("ea = 1000.0", "ea = 1e308", 1), "cables[0].ea", "1e308", "[1e-6, 1e12] N"),
        (VALID.replacen("ea = 1000.0", "ea = 1e-308", 1), "cables[0].ea", "1e-308", "[1e-6, 1e12] N"),
        (
            VALID.replacen("rest_length = 0.9", "damping_ratio = 1e308\nrest_length = 0.9", 1),
            "cables[0].damping_ratio",
            "1e308",
            "[0, 100]",
        ),
        (VALID.replace("mass = 2.0", "mass = 1e300"), "bodies[2].mass", "1e300", "[1e-9, 1e9] kg"),
        (
            VALID.replacen("rest_length = 0.9", "rest_length = 1e300", 1),
            "cables[0].rest_length",
            "1e300",
            "[1e-9, 1e6] m",
        ),
    ];
    for (text, field, marker, reason) in cases {
        let line = 1 + text.lines().position(|l| l.contains(marker)).unwrap();
        expect(&text, field, line, reason);
    }
}

#[test]
fn endless_deployments_and_steps_outside_the_node_range_are_refused() {
    let with_deployment = |steps: &str, duration: &str| {
        format!(
            "{VALID}\n[[actuators]]\nname = \"w\"\ncable = \"stay\"\nmin_rest_length = 0.5\nmax_rest_length = 1.0\nmax_rate = 1.0\n\n[deployment]\nsteps = {steps}\n\n[[deployment.ramps]]\nactuator = \"w\"\nstart = 0.0\nduration = {duration}\nrest_length = 0.8\n"
        )
    };
    let e = error_of(&with_deployment("4611686018427387904", "1.0"));
    assert!(e.field == "deployment" && e.reason.contains("[1, 1000000]"), "{e}");
    let e = error_of(&with_deployment("10", "1e308"));
    assert!(e.field == "deployment.ramps[0].duration" && e.reason.contains("[0, 1e6] s"), "{e}");
    let e = error_of(&VALID.replace("name = \"ok\"", "name = \"ok\"\nphysics_dt = 10.0"));
    assert!(e.field == "physics_dt" && e.reason.contains("[1e-6, 0.1] s"), "{e}");
}

#[test]
fn a_repeated_joint_is_refused_as_redundant() {
    let twice = VALID.replace(
        "[[joints]]\nkind = \"pin\"\na = \"pole.a\"\n",
        "[[joints]]\nkind = \"pin\"\na = \"pole.a\"\n\n[[joints]]\nkind = \"pin\"\na = \"pole.a\"\n",
    );
    let e = error_of(&twice);
    assert!(e.field == "joints[1].a" && e.reason.contains("joints[0] already holds these points"), "{e}");
}

/// Joints that repeat what earlier joints impose, without being the same joint: the joint
/// Jacobian loses rank at the initial pose, and the message names the joint and the ones it
/// repeats (the statics issue's cases: a bar pinned at both ends, and at its middle too; three
/// bars joined pairwise at one point).
#[test]
fn joints_that_repeat_earlier_joints_are_refused_by_name() {
    let bar = |pins: &[&str]| {
        let mut text = String::from(
            "[[bodies]]\nname = \"rod\"\nkind = \"bar\"\nmass = 1.0\nends = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]\npoints = { mid = 0.5 }\n",
        );
        for p in pins {
            text += &format!("\n[[joints]]\nkind = \"pin\"\na = \"rod.{p}\"\n");
        }
        text
    };
    // pinned at both ends: the bar's length already fixes one of the second pin's equations
    let e = error_of(&bar(&["a", "b"]));
    assert_eq!(e.field, "joints[1].a", "{e}");
    assert_eq!(e.line, Some(14), "{e}");
    assert!(e.reason.contains("redundant: 1 of its 3 equations is implied by joints[0]"), "{e}");
    // ... and at its middle: refused at the first joint that repeats anything
    let e = error_of(&bar(&["a", "mid", "b"]));
    assert!(e.field == "joints[1].a" && e.reason.contains("implied by joints[0]"), "{e}");
    // a middle pin after two end pins repeats all three of its equations, implied by both
    let e = error_of(
        &bar(&["a", "b", "mid"])
            .replace(
                "kind = \"bar\"",
                "kind = \"rigid\"\ninertia = [1.0, 1.0, 1.0]\nposition = [1.0, 0.0, 0.0]",
            )
            .replace(
                "ends = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]\npoints = { mid = 0.5 }",
                "points = { a = [-1.0, 0.0, 0.0], b = [1.0, 0.0, 0.0], mid = [0.0, 0.0, 0.0] }",
            ),
    );
    assert!(
        e.field == "joints[1].a" && e.reason.contains("1 of its 3 equations is implied by joints[0]"),
        "{e}"
    );
    // three bars meeting at one point, joined pairwise: the third joint closes a loop
    let mut three =
        String::from("[[bodies]]\nname = \"g\"\nkind = \"fixed\"\npoints = { p = [0.0, 0.0, 0.0] }\n");
    for (name, end) in [("x", "[1.0, 0.0, 0.0]"), ("y", "[0.0, 1.0, 0.0]"), ("z", "[0.0, 0.0, 1.0]")] {
        three += &format!(
            "\n[[bodies]]\nname = \"{name}\"\nkind = \"bar\"\nmass = 1.0\nends = [[0.0, 0.0, 0.0], {end}]\n"
        );
    }
    three += "\n[[joints]]\nkind = \"pin\"\na = \"x.a\"\n";
    for (a, b) in [("x", "y"), ("y", "z"), ("z", "x")] {
        three += &format!("\n[[joints]]\nkind = \"ball\"\na = \"{a}.a\"\nb = \"{b}.a\"\n");
    }
    let e = error_of(&three);
    assert_eq!(e.field, "joints[3].a", "{e}");
    assert!(e.reason.contains("3 of its 3 equations are implied by joints[1] and joints[2]"), "{e}");
    // the same structures without the repeats are fine
    assert!(from_toml(&bar(&["a"]), "scene.toml").is_ok());
    let open_loop = three.rsplit_once("\n[[joints]]").unwrap().0.to_string();
    assert!(from_toml(&open_loop, "scene.toml").is_ok());
}

#[test]
fn a_route_of_more_than_a_thousand_points_is_refused() {
    let long: Vec<&str> = std::iter::repeat_n(["\"ground.top\"", "\"pole.b\""], 501).flatten().collect();
    let text =
        VALID.replace("route = [\"ground.top\", \"pole.b\"]", &format!("route = [{}]", long.join(", ")));
    let e = error_of(&text);
    assert!(e.field == "cables[0].route" && e.reason.contains("at most 1000 points, got 1002"), "{e}");
}

#[test]
fn bodies_that_nothing_holds_are_named() {
    let model = from_toml(
        &VALID.replace("[[joints]]", "[[bodies]]\nname = \"drifter\"\nkind = \"node\"\nmass = 1.0\nposition = [5.0, 5.0, 5.0]\n\n[[joints]]"),
        "scene.toml",
    )
    .expect("a free-floating body is a valid scene for dynamics");
    let note = tensegrity::report::unheld_bodies_note(&model).expect("named");
    assert!(note.contains("1 body 'drifter' has no cable, joint or support"), "{note}");
    assert!(tensegrity::report::unheld_bodies_note(&from_toml(VALID, "scene.toml").unwrap()).is_none());
}

/// The labels the newcomer issue found wrong: a missing field is named in its own table (not the
/// previous one), the table header's line is given, messages use the format's words, not type
/// names, and a file that is not UTF-8 gets a line and column.
#[test]
fn errors_point_at_the_right_table_and_use_the_formats_words() {
    // 1-based line of the `k`-th (0-based) occurrence of `header`
    let header_line = |header: &str, k: usize| {
        VALID.lines().enumerate().filter(|(_, l)| l.trim() == header).nth(k).map(|(i, _)| i + 1)
    };
    let e = error_of(&VALID.replacen("ea = 1000.0\n", "", 1));
    assert_eq!((e.field.as_str(), e.line), ("cables[0].ea", header_line("[[cables]]", 0)), "{e}");
    assert!(e.reason.contains("missing field `ea`"), "{e}");
    let e = error_of(&VALID.replacen("name = \"pole\"\n", "", 1));
    assert_eq!((e.field.as_str(), e.line), ("bodies[1].name", header_line("[[bodies]]", 1)), "{e}");
    let e = error_of(&VALID.replace("name = \"ok\"", "name = \"ok\"\nsolver = 3"));
    assert_eq!(e.field, "solver", "{e}");
    assert!(e.reason.contains("expected a [solver] table") && !e.reason.contains("Spec"), "{e}");
    let e = error_of(&VALID.replace("points = { hook = [0.0, 0.0, 0.2] }", "points = { hook = \"x\" }"));
    assert!(!e.reason.contains("PointSpec") && e.reason.contains("a point"), "{e}");

    let dir = std::env::temp_dir().join(format!("tensegrity-utf8-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("latin1.toml");
    std::fs::write(&path, b"name = \"ok\"\ndescription = \"caf\xe9\"\n").unwrap();
    let e = tensegrity::scene::load(&path).unwrap_err();
    assert_eq!(e.line, Some(2), "{e}");
    assert!(e.reason.contains("not UTF-8") && e.reason.contains("column 19"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

/// Invariant: the redundancy check works group by group of joined bodies, so it covers large
/// structures too (it used to skip any scene with more than 4000 joint equations): among 1400
/// separately pinned bars (4200 equations), the last one pinned at its other end as well is
/// refused by name, and the same scene without that pin is valid.
#[test]
fn a_redundant_joint_among_thousands_is_refused_by_name() {
    let mut text = String::new();
    for i in 0..1400 {
        text += &format!(
            "[[bodies]]\nname = \"rod{i}\"\nkind = \"bar\"\nmass = 1.0\nends = [[{i}.0, 0.0, 0.0], [{i}.0, 0.0, -1.0]]\n\n[[joints]]\nkind = \"pin\"\na = \"rod{i}.a\"\n\n"
        );
    }
    tensegrity::scene::from_toml(&text, "rods.toml").unwrap_or_else(|e| panic!("{e}"));
    text += "[[joints]]\nkind = \"pin\"\na = \"rod1399.b\"\n";
    let e = error_of(&text);
    assert_eq!(e.field, "joints[1400].a", "{e}");
    assert!(e.reason.contains("redundant: 1 of its 3 equations is implied by joints[1399]"), "{e}");
}
