//! Invariant: the README and the pages of `docs/` show only scenes that work. Every TOML block in
//! them is, verbatim, a file in `config/examples/`, and that file loads, passes `check` with no
//! warning, and has an equilibrium that `statics` finds from the pose as written, without
//! negative stiffness. One default release build serves the CLI, the node and the kits, and no
//! documented cargo command asks for features.

mod common;

use tensegrity::evaluate::Workspace;
use tensegrity::solve::statics::StaticSolver;
use tensegrity::{report, State};

#[test]
fn every_toml_block_of_the_readme_is_a_bundled_example_that_loads_and_solves() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let readme = common::user_docs();
    let examples: Vec<(std::path::PathBuf, String)> = std::fs::read_dir(root.join("config/examples"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| (p.clone(), std::fs::read_to_string(&p).unwrap()))
        .collect();
    let blocks: Vec<&str> = readme
        .split("```toml\n")
        .skip(1)
        .map(|rest| &rest[..rest.find("```").expect("closed block")])
        .collect();
    assert!(!blocks.is_empty(), "the docs show a scene");
    for block in blocks {
        let (path, _) = examples.iter().find(|(_, text)| text == block).unwrap_or_else(|| {
            panic!("this block of the README or docs/ is not a file in config/examples/:\n{block}")
        });
        let model = tensegrity::scene::load(path).unwrap_or_else(|e| panic!("{e}"));
        assert!(report::unheld_bodies_note(&model).is_none());
        let mut state = State::initial(&model);
        let mut ws = Workspace::new(&model);
        let r = StaticSolver::new(&model)
            .equilibrate(&model, &mut state, &mut ws, &model.solver)
            .unwrap_or_else(|e| panic!("{}: no equilibrium: {e:?}", path.display()));
        assert_eq!(r.negative_modes, 0, "{}: {}", path.display(), r.stability_words());
    }
}

#[test]
fn the_readme_field_reference_is_generated_and_lists_exactly_the_parsed_fields() {
    use std::collections::BTreeSet;
    use tensegrity::scene::reference::{markdown, scene_fields, TABLES};
    let readme = common::user_docs();
    let expected = format!("<!-- fields:begin -->\n{}<!-- fields:end -->", markdown());
    assert!(
        readme.contains(&expected),
        "the field table of docs/scene-format.md differs from `tensegrity fields`: paste its output between the markers"
    );
    // the parser's own list: an unknown key in each table is refused with the accepted ones
    for (table, key) in TABLES {
        let text = match key {
            "" => "bogus = 1\n".to_string(),
            "deployment.ramps" => "[deployment]\nsteps = 1\n[[deployment.ramps]]\nbogus = 1\n".to_string(),
            "actuators.winch" => "[[actuators]]\nname = \"a\"\n[actuators.winch]\nbogus = 1\n".to_string(),
            k if table.starts_with("[[") => format!("[[{k}]]\nbogus = 1\n"),
            k => format!("[{k}]\nbogus = 1\n"),
        };
        let err =
            tensegrity::scene::parse(&text, "fields.toml").expect_err("unknown field refused").to_string();
        let after = &err[err.find("expected").unwrap_or_else(|| panic!("{table}: {err}"))..];
        let tables: BTreeSet<&str> = TABLES.iter().map(|t| t.1).collect();
        let accepted: BTreeSet<&str> =
            after.split('`').skip(1).step_by(2).filter(|k| !key.is_empty() || !tables.contains(k)).collect();
        let documented: BTreeSet<&str> =
            scene_fields().iter().filter(|d| d.table == table).map(|d| d.field).collect();
        assert_eq!(documented, accepted, "{table}: documented fields vs the parser's ({err})");
    }
}

/// Invariant: the test-kit examples of the README and docs/ are the kits' tests. Every ```rust and ```python
/// block whose first line names a file (`// tests/kit.rs`, `# python/tests/...`) is, piece by
/// piece (pieces split at `// ...` and `# ...` lines), verbatim text of that file.
#[test]
fn the_readmes_kit_examples_are_verbatim_parts_of_tested_files() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let readme = common::user_docs();
    let mut checked = 0;
    for (fence, comment) in [("```rust\n", "// "), ("```python\n", "# ")] {
        for rest in readme.split(fence).skip(1) {
            let block = &rest[..rest.find("```").expect("closed block")];
            let first = block.lines().next().unwrap_or("");
            let Some(named) = first.strip_prefix(comment) else { continue };
            let file = named.split([',', ' ']).next().unwrap();
            if !(file.starts_with("tests/") || file.starts_with("python/")) {
                continue;
            }
            let text = std::fs::read_to_string(root.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
            let body: Vec<&str> = block.lines().skip(1).collect();
            let elision = format!("{comment}...");
            for piece in body.split(|l| *l == elision) {
                let piece = piece.join("\n");
                assert!(
                    text.contains(&piece),
                    "this piece of the README or docs/ is not in {file}:\n{piece}"
                );
            }
            checked += 1;
        }
    }
    assert!(checked >= 4, "the docs show the Rust and Python kit examples ({checked} blocks found)");
}

#[test]
fn one_default_build_serves_the_cli_the_node_and_the_kits() {
    // a plain `cargo build --release` (benches/check_scaling.sh, the MuJoCo comparison, a user)
    // must not replace the node with one that has no transport
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let manifest: toml::Table = std::fs::read_to_string(root.join("Cargo.toml")).unwrap().parse().unwrap();
    let default = manifest["features"]["default"].as_array().expect("a default feature list");
    for feature in ["ros2", "shm"] {
        assert!(default.iter().any(|f| f.as_str() == Some(feature)), "default features lack {feature}");
    }
    // the user's documentation builds and runs with the default features only
    let docs = common::user_docs();
    let naming: Vec<&str> =
        docs.lines().filter(|l| l.contains("cargo ") && l.contains("--features")).collect();
    assert!(naming.is_empty(), "documented commands name features the default build has: {naming:?}");
}
