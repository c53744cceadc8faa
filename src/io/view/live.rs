//! A running node for the viewer: takes a node's shared-memory prefix and the scene it runs,
//! gives frames of its newest states as it steps (`follow`), into a `FrameStore`, with what the
//! node says of itself (playing, paused, faulted) and when it stops. It reads through an
//! `ShmObserver`: the node never waits for the viewer and is never woken by it.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use super::{Frame, FrameStore, ViewGeometry};
use crate::io::shm::{ContactsSample, ShmObserver, StateSample, Structure};
use crate::model::{Model, Pose};

/// How often the viewer takes the node's newest state (a browser draws at most about this).
pub const LIVE_RATE_HZ: f64 = 60.0;
/// How long without a state before the page says the node is quiet.
const QUIET_AFTER: Duration = Duration::from_secs(1);

/// Checks that the node's `structure` is `model`'s (the same body and cable names, in order), or
/// says how they differ.
pub fn check_structure(model: &Model, structure: &Structure, prefix: &str) -> Result<(), String> {
    let bodies: Vec<&str> = model.bodies.iter().map(|b| b.name.as_str()).collect();
    let cables: Vec<&str> = model.cable_names.iter().map(String::as_str).collect();
    if structure.body_names != bodies || structure.cable_names != cables {
        return Err(format!(
            "the node at '{prefix}' runs scene '{}' ({} bodies, {} cables), not '{}' ({} bodies, {} cables): give the scene file the node was started with",
            structure.scene_name,
            structure.body_names.len(),
            structure.cable_names.len(),
            model.name,
            bodies.len(),
            cables.len()
        ));
    }
    Ok(())
}

/// The frame of a node's state sample (and its newest contacts sample, if any).
pub fn frame_of(
    model: &Model,
    geometry: &ViewGeometry,
    s: &StateSample,
    contacts: Option<&ContactsSample>,
) -> Frame {
    let nb = model.bodies.len().min(s.body_count as usize);
    let poses: Vec<Pose> = (0..nb)
        .map(|b| {
            let [x, y, z] = s.body_position[b];
            let [qx, qy, qz, qw] = s.body_orientation[b];
            Pose {
                position: Vector3::new(x, y, z),
                rotation: UnitQuaternion::from_quaternion(Quaternion::new(qw, qx, qy, qz)),
            }
        })
        .collect();
    let nc = model.cables.len().min(s.cable_count as usize);
    let mut frame = Frame {
        time: s.time,
        step: s.step,
        vertices: if nb == model.bodies.len() { geometry.vertices(model, &poses) } else { Vec::new() },
        tension: s.cable_tension[..nc].to_vec(),
        rest_length: s.cable_rest_length[..nc].to_vec(),
        slack: s.cable_slack[..nc].iter().map(|k| *k != 0).collect(),
        contacts: Vec::new(),
    };
    if let Some(c) = contacts {
        for i in 0..(c.contact_count as usize).min(c.in_contact.len()) {
            if c.in_contact[i] != 0 {
                let [px, py, pz] = c.position[i];
                let f = Vector3::from(c.normal[i]) * c.normal_force[i] + Vector3::from(c.friction[i]);
                frame.contacts.push([px, py, pz, f.x, f.y, f.z]);
            }
        }
    }
    frame
}

/// Follows the node `observer` watches until `stop` is set: about `LIVE_RATE_HZ` times a second
/// its newest state (if a new one came) becomes a frame in `store`, and the store's status says
/// what the node says (`playing`, `paused`, `faulted`), `waiting` while no state comes, and
/// `stopped` once the node's state publisher is gone (then it returns). Returns why it ended.
pub fn follow(
    model: &Model,
    geometry: &ViewGeometry,
    observer: &ShmObserver,
    store: &FrameStore,
    stop: &AtomicBool,
) -> String {
    let period = Duration::from_secs_f64(1.0 / LIVE_RATE_HZ);
    let mut last_state = Instant::now();
    let mut last_time = None::<f64>;
    let mut last_said = "waiting";
    let mut contacts: Option<ContactsSample> = None;
    while !stop.load(Ordering::Relaxed) {
        let tick = Instant::now();
        if let Ok(Some(c)) = observer.newest_contacts() {
            contacts = Some(c.payload().clone());
        }
        match observer.newest_state() {
            Ok(Some(s)) => {
                let s = s.payload();
                last_state = Instant::now();
                last_time = Some(s.time);
                store.push(&frame_of(model, geometry, s, contacts.as_ref()));
                let (state, message) = if s.faulted != 0 {
                    ("faulted", "the node holds a physics failure (paused until reset)")
                } else if s.simulation_state == 2 {
                    ("paused", "")
                } else {
                    ("playing", "")
                };
                store.set_status(state, message);
                last_said = state;
            }
            Ok(None) if last_state.elapsed() > QUIET_AFTER => {
                if !observer.node_alive() {
                    let why = match last_time {
                        Some(t) => format!(
                            "the node at '{}' stopped (last state at t = {t:.3} s)",
                            observer.prefix()
                        ),
                        None => format!("the node at '{}' stopped before sending a state", observer.prefix()),
                    };
                    store.set_status("stopped", &why);
                    return why;
                }
                if last_said != "paused" && last_said != "faulted" {
                    store.set_status(
                        "waiting",
                        &format!(
                            "no state from the node at '{}' for {:.0} s (paused, or publishing slower)",
                            observer.prefix(),
                            last_state.elapsed().as_secs_f64()
                        ),
                    );
                }
            }
            Ok(None) => {}
            Err(e) => {
                let why = format!("lost the node at '{}': {e}", observer.prefix());
                store.set_status("stopped", &why);
                return why;
            }
        }
        std::thread::sleep(period.saturating_sub(tick.elapsed()));
    }
    String::from("the viewer stopped")
}
