//! The software renderer (`tensegrity::render`): frames of bundled scenes show their struts and
//! cables where the camera frames them, the same state gives the same pixels, a state that moved
//! gives others, and careless sizes and states do not panic.

mod common;

use tensegrity::render::{primitives, render_rgb, CableLook, Camera};
use tensegrity::sim::{SimSettings, Simulator};

const SIZE: (usize, usize) = (320, 240);

fn frame(sim: &Simulator) -> Vec<u8> {
    let (model, state, ws) = (sim.model(), sim.state(), sim.workspace());
    let camera = Camera::framing(model, ws, SIZE.0 as f64 / SIZE.1 as f64);
    let mut rgb = Vec::new();
    render_rgb(model, state, ws, &camera, SIZE, &mut rgb);
    if let Some(dir) = std::env::var_os("TENSEGRITY_RENDER_DIR") {
        // a look at the frame: TENSEGRITY_RENDER_DIR=/tmp cargo test --test render
        let name = format!("{}-{:.3}.ppm", model.name, state.time);
        let mut ppm = format!("P6 {} {} 255\n", SIZE.0, SIZE.1).into_bytes();
        ppm.extend_from_slice(&rgb);
        std::fs::write(std::path::Path::new(&dir).join(name), ppm).unwrap();
    }
    rgb
}

/// Pixels of `rgb` within `tol` of `colour`, and how many of them lie in the frame's middle half
/// (both ways).
fn pixels_of(rgb: &[u8], colour: [u8; 3], tol: i32) -> (usize, usize) {
    let (mut all, mut middle) = (0, 0);
    for (i, px) in rgb.chunks_exact(3).enumerate() {
        if px.iter().zip(colour).all(|(a, b)| (*a as i32 - b as i32).abs() <= tol) {
            all += 1;
            let (x, y) = (i % SIZE.0, i / SIZE.0);
            middle +=
                usize::from(x >= SIZE.0 / 4 && x < 3 * SIZE.0 / 4 && y >= SIZE.1 / 4 && y < 3 * SIZE.1 / 4);
        }
    }
    (all, middle)
}

#[test]
fn the_six_bar_shows_its_struts_and_cables_in_the_middle_above_its_grid() {
    let model = common::bundled("sixbar.toml");
    let mut sim = Simulator::new(model, SimSettings::default()).unwrap();
    let first = frame(&sim);
    assert_eq!(first.len(), SIZE.0 * SIZE.1 * 3);
    assert_eq!(first, frame(&sim), "the same state, the same pixels");
    let (struts, middle) = pixels_of(&first, [70, 76, 92], 6);
    assert!(struts > 800 && middle > struts / 2, "strut pixels {struts}, {middle} in the middle");
    assert!(pixels_of(&first, [196, 200, 208], 2).0 > 500, "the ground's grid");
    assert_eq!(&first[..3], &[238, 240, 244], "the sky in the top corner");
    // six struts (a bar's centre to each end: two lines each), 24 cables, 3 feet pressing
    let p = primitives(sim.model(), sim.state(), sim.workspace());
    assert_eq!((p.struts.len(), p.cables.len()), (12, 24));
    assert!(p.cables.iter().all(|(_, look)| matches!(look, CableLook::Taut(s) if *s > 0.0 && *s <= 1.0)));
    for _ in 0..300 {
        sim.step().unwrap();
    }
    assert_eq!(primitives(sim.model(), sim.state(), sim.workspace()).contacts.len(), 3, "three feet");
    assert!(pixels_of(&frame(&sim), [26, 160, 60], 10).0 > 20, "the feet's contact discs");
    assert_ne!(frame(&sim), first, "a state that moved looks different");
}

#[test]
fn cables_are_blue_to_red_by_tension_and_slack_ones_pale() {
    // the prism's clustered ring carries less than its side strings: two colours of cable, the
    // most taut pure red
    let sim = Simulator::new(common::bundled("prism3.toml"), SimSettings::default()).unwrap();
    let rgb = frame(&sim);
    let mut colours: Vec<[u8; 3]> = rgb
        .chunks_exact(3)
        .filter(|px| px[1] == 40 && px[0] != px[2])
        .map(|px| [px[0], px[1], px[2]])
        .collect();
    colours.sort();
    colours.dedup();
    assert!(colours.len() >= 2 && colours.contains(&[255, 40, 40]), "{colours:?}");
    let p = primitives(sim.model(), sim.state(), sim.workspace());
    assert!(p.cables.iter().any(|c| matches!(c.1, CableLook::Taut(s) if s < 0.99)), "{:?}", p.cables);
    // a cable given a rest length far above its length is slack: pale grey, thinner
    let model = common::bundled("prism3.toml");
    let mut state = tensegrity::State::initial(&model);
    for l in state.rest_lengths.iter_mut() {
        *l *= 2.0;
    }
    let mut ws = tensegrity::Workspace::for_forces(&model);
    tensegrity::evaluate::evaluate_forces(&model, &state, &mut ws);
    let p = primitives(&model, &state, &ws);
    assert!(p.cables.iter().all(|(_, look)| *look == CableLook::Slack));
    let camera = Camera::framing(&model, &ws, 4.0 / 3.0);
    let mut rgb = Vec::new();
    render_rgb(&model, &state, &ws, &camera, SIZE, &mut rgb);
    let pale = pixels_of(&rgb, [200, 200, 200], 12).0;
    assert!(pale > 60, "slack cable pixels {pale}");
}

#[test]
fn careless_sizes_and_states_give_a_frame_and_no_panic() {
    let sim = Simulator::new(common::bundled("sixbar.toml"), SimSettings::default()).unwrap();
    let (model, ws) = (sim.model(), sim.workspace());
    let mut rgb = vec![1, 2, 3];
    for size in [(0, 0), (1, 1), (0, 10), (3, 2000)] {
        let camera = Camera::framing(model, ws, size.0 as f64 / size.1.max(1) as f64);
        render_rgb(model, sim.state(), ws, &camera, size, &mut rgb);
        assert_eq!(rgb.len(), size.0 * size.1 * 3);
    }
    // a state with NaN positions draws nothing of it, and a camera inside the structure too
    let mut state = sim.state().clone();
    state.poses[0].position.x = f64::NAN;
    let mut bad = tensegrity::Workspace::for_forces(model);
    tensegrity::evaluate::evaluate_forces(model, &state, &mut bad);
    let camera = Camera::framing(model, &bad, 4.0 / 3.0);
    render_rgb(model, &state, &bad, &camera, SIZE, &mut rgb);
    assert_eq!(rgb.len(), SIZE.0 * SIZE.1 * 3);
    let inside =
        Camera { eye: nalgebra::Vector3::new(0.0, 0.0, 0.3), ..Camera::framing(model, ws, 4.0 / 3.0) };
    render_rgb(model, sim.state(), ws, &inside, SIZE, &mut rgb);
    assert_eq!(rgb.len(), SIZE.0 * SIZE.1 * 3);
}
