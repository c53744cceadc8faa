//! `tensegrity fields`: the scene-file field reference as a Markdown table.

use tensegrity::scene;

use crate::output::emit;

/// Prints the field reference.
pub fn run() -> Result<(), String> {
    emit(&scene::reference::markdown());
    Ok(())
}
