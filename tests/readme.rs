//! Invariant: the README shows only scenes that work. Every TOML block in README.md is, verbatim,
//! a file in `config/examples/`, and that file loads, passes `check` with no warning, and has an
//! equilibrium that `statics` finds from the pose as written, without negative stiffness.

use tensegrity::forces::Workspace;
use tensegrity::solve::statics::StaticSolver;
use tensegrity::{report, State};

#[test]
fn every_toml_block_of_the_readme_is_a_bundled_example_that_loads_and_solves() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
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
    assert!(!blocks.is_empty(), "the README shows a scene");
    for block in blocks {
        let (path, _) = examples
            .iter()
            .find(|(_, text)| text == block)
            .unwrap_or_else(|| panic!("this README block is not a file in config/examples/:\n{block}"));
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
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let expected = format!("<!-- fields:begin -->\n{}<!-- fields:end -->", markdown());
    assert!(
        readme.contains(&expected),
        "the README's field table differs from `tensegrity fields`: paste its output between the markers"
    );
    // the parser's own list: an unknown key in each table is refused with the accepted ones
    for (table, key) in TABLES {
        let text = match key {
            "" => "bogus = 1\n".to_string(),
            "deployment.ramps" => "[deployment]\nsteps = 1\n[[deployment.ramps]]\nbogus = 1\n".to_string(),
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
