//! `tensegrity check SCENE`: validates a scene and prints counts of its bodies, coordinates,
//! constraints, cables, pulleys and actuators.

use std::path::Path;

use tensegrity::report;

use crate::output::*;

/// Runs `check` on the scene file `scene`.
pub fn run(scene: &Path) -> Result<(), String> {
    let model = load(scene)?;
    let s = report::summary(&model);
    say!("{}: valid scene '{}'", scene.display(), s.name);
    say!(
        "bodies: {} ({} node, {} bar, {} rigid, {} fixed)",
        s.bodies.iter().sum::<usize>(),
        s.bodies[0],
        s.bodies[1],
        s.bodies[2],
        s.bodies[3]
    );
    say!("coordinates: {}", s.coordinates);
    say!("constraints: {}", s.constraints);
    say!("cables: {} ({} sliding)", s.cables, s.sliding_cables);
    say!("pulleys: {}", s.pulleys);
    say!("actuators: {} (schedule: {})", s.actuators, counted(s.ramps, "ramp"));
    if s.planar {
        say!("planar: yes (xy plane)");
    }
    if let Some(note) = report::unheld_bodies_note(&model) {
        say!("warning: {note} (dynamics lets them drift or fall)");
    }
    Ok(())
}
