//! Scene files: takes TOML text (or a generated `SceneSpec`), gives a validated `Model` with its
//! rest lengths (given, or found by form finding), or a `SceneError` naming file, line, field and
//! reason. Unknown fields are rejected.
//!
//! Units are SI (m, kg, s, N). Positions are world coordinates (z up); rotations are rotation
//! vectors (axis times angle, rad) from body to world frame. A point is referred to as
//! `body.point`, or `body` for the body's origin (its centre of mass); bars have the points `a`
//! and `b` at their ends.

mod build;
pub mod generate;
pub mod reference;
mod spec;

use std::path::Path;

use crate::error::SceneError;
use crate::model::Model;

pub use build::build_model;
pub use spec::*;

/// The scenes bundled with the crate (the files of `config/scenes/`, compiled into the library):
/// name (the file name without `.toml`) and TOML text.
pub const BUNDLED: &[(&str, &str)] = &[
    ("atwood", include_str!("../../config/scenes/atwood.toml")),
    ("prism3", include_str!("../../config/scenes/prism3.toml")),
    ("prism3_nodal", include_str!("../../config/scenes/prism3_nodal.toml")),
    ("tbar", include_str!("../../config/scenes/tbar.toml")),
    ("tbar_nodal", include_str!("../../config/scenes/tbar_nodal.toml")),
    ("tower", include_str!("../../config/scenes/tower.toml")),
    ("sixbar", include_str!("../../config/scenes/sixbar.toml")),
    ("sixbar_rover", include_str!("../../config/scenes/sixbar_rover.toml")),
];

/// The TOML text of the bundled scene `name` (`prism3` or `prism3.toml`), if there is one.
pub fn bundled_text(name: &str) -> Option<&'static str> {
    let name = name.strip_suffix(".toml").unwrap_or(name);
    BUNDLED.iter().find(|(n, _)| *n == name).map(|(_, text)| *text)
}

/// The bundled scene `name` (`prism3` or `prism3.toml`; see `BUNDLED`), read and validated as
/// `config/scenes/NAME.toml` (the label its errors and run records name); an unknown name is an
/// error that lists the bundled ones.
pub fn bundled(name: &str) -> Result<Model, SceneError> {
    let stem = name.strip_suffix(".toml").unwrap_or(name);
    let label = format!("config/scenes/{stem}.toml");
    match bundled_text(stem) {
        Some(text) => from_toml(text, &label),
        None => Err(SceneError {
            file: format!("bundled:{stem}"),
            line: None,
            field: String::new(),
            reason: format!(
                "no bundled scene '{stem}' (bundled: {}){}",
                BUNDLED.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", "),
                crate::error::did_you_mean(stem, BUNDLED.iter().map(|(n, _)| *n)),
            ),
        }),
    }
}

/// Reads and validates a scene file.
pub fn load(path: &Path) -> Result<Model, SceneError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| SceneError {
        file: file.clone(),
        line: None,
        field: String::new(),
        reason: format!("cannot read: {e}"),
    })?;
    let text = String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let before = &e.as_bytes()[..at];
        let line = before.iter().filter(|b| **b == b'\n').count() + 1;
        let column = at - before.iter().rposition(|b| *b == b'\n').map_or(0, |i| i + 1) + 1;
        SceneError {
            file: file.clone(),
            line: Some(line),
            field: String::new(),
            reason: format!("not UTF-8 text: invalid byte 0x{:02x} at column {column}", e.as_bytes()[at]),
        }
    })?;
    from_toml(&text, &file)
}

/// Parses and validates scene text; `file` names it in errors.
pub fn from_toml(text: &str, file: &str) -> Result<Model, SceneError> {
    let spec = parse(text, file)?;
    build_model(&spec, file, Some(text))
}

/// `model` (built from a scene with `[randomize]`) drawn anew for episode `episode`: its scene
/// text built again with the seed `seed + episode` (`Model::randomization`). The same episode
/// gives the same model to the bit; a model without randomization comes back as it is.
pub fn redraw(model: &Model, episode: u64) -> Result<Model, SceneError> {
    let Some(r) = &model.randomization else { return Ok(model.clone()) };
    draw(model, r.seed, episode, &format!("{} (episode {episode})", model.name))
}

/// `model` (built from a scene with `[randomize]`) drawn anew from the seed `seed` (episode 0 of
/// that seed): a seeded reset's episode (`crate::io::node::NodeCore::reset_seeded`). The same
/// seed gives the same model to the bit; a model without randomization comes back as it is.
pub fn redraw_seeded(model: &Model, seed: u64) -> Result<Model, SceneError> {
    if model.randomization.is_none() {
        return Ok(model.clone());
    }
    draw(model, seed, 0, &format!("{} (seed {seed})", model.name))
}

/// `model`'s scene text built again with its randomization's seed `seed + episode`, labelled
/// `file` in errors.
fn draw(model: &Model, seed: u64, episode: u64, file: &str) -> Result<Model, SceneError> {
    let mut spec = parse(&model.source, file)?;
    if let Some(declared) = &mut spec.randomize {
        declared.seed = seed.wrapping_add(episode);
    }
    let mut drawn = build_model(&spec, file, Some(&model.source))?;
    drawn.name.clone_from(&model.name);
    if let Some(d) = &mut drawn.randomization {
        d.seed = seed;
        d.episode = episode;
    }
    Ok(drawn)
}
