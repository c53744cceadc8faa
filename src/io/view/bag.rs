//! A bag for the viewer: takes a rosbag2 bag the node or an offline run recorded (and, if given,
//! the scene the user says it is of), gives its model (from the scene text the bag carries) and
//! its frames: the exact body poses, cable states and contacts of each recorded step (the
//! `ground_truth` topics where the scene's sensors made the others measured), at most `fps`
//! frames per simulated second.

use std::path::Path;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use super::{Frame, ViewGeometry};
use crate::io::msg::{CableStates, ContactStates, PoseArray};
use crate::io::record::bag::BagReader;
use crate::model::{Model, Pose};

/// A bag read for viewing.
pub struct BagView {
    /// The recorded scene's model.
    pub model: Model,
    /// Where the scene came from (`sixbar.toml (recorded)`).
    pub label: String,
    /// The frames, in recorded order.
    pub frames: Vec<Frame>,
    /// Recorded steps with poses and cable states.
    pub steps: u64,
    /// Why reading stopped before the end (a bag cut short or damaged), if it did.
    pub cut_short: Option<String>,
}

/// Which topic a message is for the viewer.
#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Poses { exact: bool },
    Cables { exact: bool },
    Contacts,
}

fn kind_of(topic: &str) -> Option<Kind> {
    let exact = topic.contains("/ground_truth/");
    if topic.ends_with("/body_poses") {
        Some(Kind::Poses { exact })
    } else if topic.ends_with("/cable_states") {
        Some(Kind::Cables { exact })
    } else if topic.ends_with("/contacts") {
        Some(Kind::Contacts)
    } else {
        None
    }
}

/// One recorded step, gathered from its messages.
#[derive(Default)]
struct Step {
    sequence: Option<u32>,
    poses: Option<(PoseArray, bool)>,
    cables: Option<(CableStates, bool)>,
    contacts: Option<ContactStates>,
}

/// Reads the bag at `path` (a rosbag2 directory or its `.mcap` file). With `scene`, the model the
/// user says it records, checked against the bag's own (body and cable names); without, the
/// scene the bag carries. Frames are kept at most `fps` per simulated second (the last one
/// always). Errors name the path and what is wrong: no bag there, no run record, a scene that
/// does not build, a bag of another scene, messages that do not fit the scene, no frame at all.
pub fn read_bag(path: &Path, scene: Option<(&Model, &str)>, fps: f64) -> Result<BagView, String> {
    let reader = BagReader::open(path).map_err(|e| e.to_string())?;
    let here = path.display();
    let run = reader.run().ok_or_else(|| {
        format!("{here}: not a bag of this simulator (no `tensegrity` run record: record it with the node or `deploy --record`)")
    })?;
    let text = run.get("scene").ok_or_else(|| format!("{here}: the run record has no scene"))?;
    let label = format!("{} (recorded)", run.get("scene_file").map_or("scene", String::as_str));
    let recorded =
        crate::scene::from_toml(text, &label).map_err(|e| format!("{here}: the recorded scene: {e}"))?;
    let (model, label) = match scene {
        None => (recorded, label),
        Some((given, given_label)) => {
            let names = |m: &Model| -> (Vec<String>, Vec<String>) {
                (m.bodies.iter().map(|b| b.name.clone()).collect(), m.cable_names.clone())
            };
            if names(given) != names(&recorded) {
                return Err(format!(
                    "{here}: the bag records scene '{}' ({} bodies, {} cables), not '{}' of {given_label} ({} bodies, {} cables); leave out --scene to view the bag's own scene",
                    recorded.name,
                    recorded.bodies.len(),
                    recorded.cables.len(),
                    given.name,
                    given.bodies.len(),
                    given.cables.len()
                ));
            }
            (given.clone(), given_label.to_string())
        }
    };
    let geometry = ViewGeometry::new(&model);
    let period = if fps > 0.0 { 1.0 / fps } else { 0.0 };
    let mut frames: Vec<Frame> = Vec::new();
    let mut last_kept = f64::NEG_INFINITY;
    let mut held: Option<Frame> = None;
    let mut steps = 0u64;
    let mut cut_short = None;
    let mut step = Step::default();
    let mut finish = |step: Step, frames: &mut Vec<Frame>, held: &mut Option<Frame>| -> Result<(), String> {
        let (Some((poses, _)), Some((cables, _))) = (step.poses, step.cables) else { return Ok(()) };
        let frame =
            frame_of(&model, &geometry, step.sequence.unwrap_or(0), &poses, &cables, step.contacts.as_ref())
                .map_err(|e| format!("{here}: step {}: {e}", step.sequence.unwrap_or(0)))?;
        steps += 1;
        if frame.time >= last_kept + period - 1e-12 || frame.time < last_kept {
            last_kept = frame.time;
            frames.push(frame);
            *held = None;
        } else {
            *held = Some(frame);
        }
        Ok(())
    };
    for message in reader.messages() {
        let message = match message {
            Ok(m) => m,
            Err(e) => {
                cut_short = Some(e);
                break;
            }
        };
        let Some(kind) = kind_of(&message.topic) else { continue };
        if step.sequence.is_some_and(|s| s != message.sequence) {
            finish(std::mem::take(&mut step), &mut frames, &mut held)?;
        }
        step.sequence = Some(message.sequence);
        let decoded = |e: String| format!("{here}: {e}");
        match kind {
            // the exact topic wins over a measured one, whichever came first
            Kind::Poses { exact } if step.poses.as_ref().is_none_or(|p| !p.1 || exact) => {
                step.poses = Some((message.decode().map_err(decoded)?, exact));
            }
            Kind::Cables { exact } if step.cables.as_ref().is_none_or(|c| !c.1 || exact) => {
                step.cables = Some((message.decode().map_err(decoded)?, exact));
            }
            Kind::Contacts => step.contacts = Some(message.decode().map_err(decoded)?),
            _ => {}
        }
    }
    finish(step, &mut frames, &mut held)?;
    frames.extend(held);
    if frames.is_empty() {
        return Err(match cut_short {
            Some(why) => format!("{here}: no recorded step could be read ({why})"),
            None => format!("{here}: the bag holds no body poses and cable states to show"),
        });
    }
    Ok(BagView { model, label, frames, steps, cut_short })
}

/// The frame of one recorded step, or why its messages do not fit `model`.
fn frame_of(
    model: &Model,
    geometry: &ViewGeometry,
    sequence: u32,
    poses: &PoseArray,
    cables: &CableStates,
    contacts: Option<&ContactStates>,
) -> Result<Frame, String> {
    if poses.poses.len() != model.bodies.len() {
        return Err(format!("{} body poses for a scene of {} bodies", poses.poses.len(), model.bodies.len()));
    }
    let n = model.cables.len();
    if cables.tension.len() != n || cables.rest_length.len() != n {
        return Err(format!("{} cable tensions for a scene of {n} cables", cables.tension.len()));
    }
    let poses: Vec<Pose> = poses
        .poses
        .iter()
        .map(|p| Pose {
            position: Vector3::new(p.position.x, p.position.y, p.position.z),
            rotation: UnitQuaternion::from_quaternion(Quaternion::new(
                p.orientation.w,
                p.orientation.x,
                p.orientation.y,
                p.orientation.z,
            )),
        })
        .collect();
    let stamp = &cables.header.stamp;
    let mut frame = Frame {
        time: f64::from(stamp.sec) + 1e-9 * f64::from(stamp.nanosec),
        step: u64::from(sequence),
        vertices: geometry.vertices(model, &poses),
        tension: cables.tension.clone(),
        rest_length: cables.rest_length.clone(),
        slack: if cables.slack.len() == n {
            cables.slack.clone()
        } else {
            cables.tension.iter().map(|t| *t <= 0.0).collect()
        },
        contacts: Vec::new(),
    };
    if let Some(c) = contacts {
        for i in 0..c.in_contact.len() {
            let (Some(p), Some(nrm), Some(fnorm), Some(fr)) =
                (c.position.get(i), c.normal.get(i), c.normal_force.get(i), c.friction.get(i))
            else {
                break;
            };
            if c.in_contact[i] {
                let f = Vector3::new(nrm.x, nrm.y, nrm.z) * *fnorm + Vector3::new(fr.x, fr.y, fr.z);
                frame.contacts.push([p.x, p.y, p.z, f.x, f.y, f.z]);
            }
        }
    }
    Ok(frame)
}
