//! Pictures of a structure with no GPU, display or browser: takes a model, a state and its
//! evaluation (`Workspace`), gives what to draw (`primitives`: struts, nodes, cable segments
//! by tension, contact points pressing in with their forces; the RViz markers draw the same)
//! and an RGB frame of it (`render_rgb`) from a camera that frames the structure
//! (`Camera::framing`), above its grounds' grid. Plain arithmetic on one thread: the same state
//! gives the same pixels, on every machine that rounds as IEEE 754 says.

use nalgebra::Vector3;

use crate::evaluate::Workspace;
use crate::model::{BodyKind, CableId, Model};
use crate::state::State;

/// How a cable segment looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CableLook {
    /// An elastic member (pushes and pulls): a strut's grey.
    Member,
    /// A taut cable, its tension over the largest of the state's cables, in `(0, 1]`.
    Taut(f32),
    /// A slack cable.
    Slack,
}

/// What a state shows, in world coordinates (m).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Primitives {
    /// Strut lines: each bar's and rigid body's centre to each of its points away from it.
    pub struts: Vec<[Vector3<f64>; 2]>,
    /// Point masses (`BodyKind::Node`).
    pub nodes: Vec<Vector3<f64>>,
    /// Cable segments, route order.
    pub cables: Vec<([Vector3<f64>; 2], CableLook)>,
    /// Contacts pressing in: the contact point and the end of its force drawn from it, the force
    /// scaled so that the largest is a fifth of the structure's size (`contact_force_scale`).
    pub contacts: Vec<[Vector3<f64>; 2]>,
    /// The scale of the contact force lines, m/N.
    pub contact_force_scale: f64,
}

/// The struts, nodes, cables and pressing contacts of the evaluated state `ws` of `state`.
pub fn primitives(model: &Model, state: &State, ws: &Workspace) -> Primitives {
    let mut out = Primitives::default();
    for (b, body) in model.bodies.iter().enumerate() {
        let origin = state.poses[b].position;
        if matches!(body.kind, BodyKind::Bar | BodyKind::Rigid) {
            for (k, _) in
                model.points.iter().enumerate().filter(|(_, p)| p.body.0 == b && p.local.norm() > 0.0)
            {
                out.struts.push([origin, ws.points[k].position]);
            }
        }
        if body.kind == BodyKind::Node {
            out.nodes.push(origin);
        }
    }
    let t_max = ws.cables.iter().map(|c| c.tension).fold(0.0, f64::max).max(1e-12);
    for c in 0..model.cables.len() {
        let r = &ws.cables[c];
        let look = if !model.cables[c].tension_only {
            CableLook::Member
        } else if r.tension > 0.0 {
            CableLook::Taut((r.tension / t_max) as f32)
        } else {
            CableLook::Slack
        };
        for w in model.route(CableId(c)).windows(2) {
            out.cables.push(([ws.points[w[0].0].position, ws.points[w[1].0].position], look));
        }
    }
    if model.contact_pairs() > 0 {
        let f_max = ws.contacts.iter().map(|c| c.normal_force).fold(0.0, f64::max).max(1e-12);
        let (lo, hi) = bounds(ws);
        out.contact_force_scale = 0.2 * (hi - lo).norm() / f_max;
        for c in ws.contacts.iter().filter(|c| c.in_contact()) {
            out.contacts.push([c.position, c.position + c.force() * out.contact_force_scale]);
        }
    }
    out
}

/// The smallest and largest coordinates of the evaluated points (`ws.points`), m.
fn bounds(ws: &Workspace) -> (Vector3<f64>, Vector3<f64>) {
    ws.points
        .iter()
        .fold((Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY)), |(lo, hi), p| {
            (lo.inf(&p.position), hi.sup(&p.position))
        })
}

/// Two unit vectors spanning the plane normal to the unit `n`: the world axis least along `n`
/// made perpendicular to it, and `n` cross that.
fn plane_basis(n: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let axis = [Vector3::x(), Vector3::y(), Vector3::z()]
        .into_iter()
        .min_by(|a, b| a.dot(n).abs().total_cmp(&b.dot(n).abs()))
        .unwrap_or(Vector3::x());
    let e1 = (axis - n * n.dot(&axis)).normalize();
    (e1, n.cross(&e1))
}

/// A pinhole camera: where it is and what it looks at (m), which way is up, its vertical field
/// of view (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position, m.
    pub eye: Vector3<f64>,
    /// The point at the centre of the frame, m.
    pub target: Vector3<f64>,
    /// Up in the frame (unit).
    pub up: Vector3<f64>,
    /// Vertical field of view, rad, in `(0, pi)`.
    pub fov_y: f64,
}

/// Elevation of `Camera::framing`'s view above the horizontal, rad (25 degrees).
pub const FRAMING_ELEVATION: f64 = 0.436;
/// Azimuth of `Camera::framing`'s view, rad from the first horizontal axis (30 degrees).
pub const FRAMING_AZIMUTH: f64 = 0.524;

impl Camera {
    /// The camera that shows the whole evaluated structure `ws` of `model` in a frame of aspect
    /// `width / height`: looking at the centre of its points' bounding box from
    /// `FRAMING_AZIMUTH` and `FRAMING_ELEVATION` (up against gravity; z without gravity), 40
    /// degrees of vertical view, far enough that the bounding sphere (radius at least 0.1 m)
    /// fits with a tenth to spare.
    pub fn framing(model: &Model, ws: &Workspace, aspect: f64) -> Self {
        let up = if model.gravity.norm() > 0.0 { -model.gravity.normalize() } else { Vector3::z() };
        let (lo, hi) = bounds(ws);
        let (centre, radius) = if lo.x.is_finite() {
            ((lo + hi) * 0.5, ((hi - lo).norm() * 0.5).max(0.1))
        } else {
            (Vector3::zeros(), 1.0)
        };
        let (h1, h2) = plane_basis(&up);
        let (ce, se) = (FRAMING_ELEVATION.cos(), FRAMING_ELEVATION.sin());
        let (ca, sa) = (FRAMING_AZIMUTH.cos(), FRAMING_AZIMUTH.sin());
        let back = (h1 * ca + h2 * sa) * ce + up * se;
        let fov_y: f64 = 40f64.to_radians();
        // the narrower of the two fields of view holds the sphere
        let half = (fov_y * 0.5).tan().min((fov_y * 0.5).tan() * aspect.max(1e-3));
        let distance = 1.1 * radius * (1.0 + half * half).sqrt() / half;
        Self { eye: centre + back * distance, target: centre, up, fov_y }
    }
}

/// Frame colours, RGB.
const SKY: [u8; 3] = [238, 240, 244];
const GRID: [u8; 3] = [196, 200, 208];
const STRUT: [u8; 3] = [70, 76, 92];
const SLACK: [u8; 3] = [200, 200, 200];
const CONTACT: [u8; 3] = [26, 160, 60];

/// The colour of a cable look: taut from blue (no tension) to red (the largest).
fn cable_colour(look: CableLook) -> [u8; 3] {
    match look {
        CableLook::Member => STRUT,
        CableLook::Slack => SLACK,
        CableLook::Taut(s) => {
            let s = s.clamp(0.0, 1.0);
            [(40.0 + 215.0 * s) as u8, 40, (255.0 - 215.0 * s) as u8]
        }
    }
}

/// A projected line of the frame: its ends in pixels, their depths (m), half its width (px)
/// and colour.
struct Stroke {
    a: [f64; 2],
    b: [f64; 2],
    depth: f64,
    half_width: f64,
    colour: [u8; 3],
}

/// Draws `model`'s evaluated state `ws` of `state` seen from `camera` into `rgb` (`width *
/// height * 3` bytes, rows top to bottom, resized to that): the sky, each ground's grid around
/// the structure, then struts (3 cm), cables (1.2 cm), nodes and contacts as discs and the
/// contacts' force lines, far before near. Deterministic for a given state and camera.
pub fn render_rgb(
    model: &Model,
    state: &State,
    ws: &Workspace,
    camera: &Camera,
    (width, height): (usize, usize),
    rgb: &mut Vec<u8>,
) {
    rgb.clear();
    rgb.resize(width * height * 3, 0);
    for px in rgb.chunks_exact_mut(3) {
        px.copy_from_slice(&SKY);
    }
    if width == 0 || height == 0 {
        return;
    }
    let forward = (camera.target - camera.eye).normalize();
    let right = forward.cross(&camera.up).normalize();
    let up = right.cross(&forward);
    let focal = 0.5 * height as f64 / (camera.fov_y * 0.5).tan();
    let (cx, cy) = (0.5 * width as f64, 0.5 * height as f64);
    let near = 1e-3;
    // a world point's pixel and depth (None behind the eye)
    let project = |p: &Vector3<f64>| {
        let d = p - camera.eye;
        let z = d.dot(&forward);
        (z > near).then(|| ([cx + focal * d.dot(&right) / z, cy - focal * d.dot(&up) / z], z))
    };
    let mut strokes: Vec<Stroke> = Vec::new();
    let line =
        |strokes: &mut Vec<Stroke>, a: &Vector3<f64>, b: &Vector3<f64>, width_m: f64, colour: [u8; 3]| {
            if let (Some((pa, za)), Some((pb, zb))) = (project(a), project(b)) {
                let depth = 0.5 * (za + zb);
                let half_width = (0.5 * width_m * focal / depth).max(0.5);
                strokes.push(Stroke { a: pa, b: pb, depth, half_width, colour });
            }
        };
    let p = primitives(model, state, ws);
    // the grounds' grid: lines a "nice" spacing apart over three times the structure's size
    let (lo, hi) = bounds(ws);
    if lo.x.is_finite() {
        let size = (hi - lo).norm().max(0.1);
        let spacing = nice_spacing(size / 4.0);
        let centre = (lo + hi) * 0.5;
        for ground in &model.grounds {
            let n = ground.normal;
            let (e1, e2) = plane_basis(&n);
            let o = centre - n * (n.dot(&centre) - ground.offset);
            let steps = (1.5 * size / spacing).ceil() as i64;
            let (s1, s2) = ((o.dot(&e1) / spacing).round(), (o.dot(&e2) / spacing).round());
            let base = o - e1 * o.dot(&e1) - e2 * o.dot(&e2);
            for k in -steps..=steps {
                let (u, v) = ((s1 + k as f64) * spacing, (s2 + k as f64) * spacing);
                let half = steps as f64 * spacing;
                let (u0, v0) = (s1 * spacing, s2 * spacing);
                let a = base + e1 * u + e2 * (v0 - half);
                let b = base + e1 * u + e2 * (v0 + half);
                line(&mut strokes, &a, &b, 0.0, GRID);
                let a = base + e2 * v + e1 * (u0 - half);
                let b = base + e2 * v + e1 * (u0 + half);
                line(&mut strokes, &a, &b, 0.0, GRID);
            }
        }
    }
    let grid = strokes.len();
    for [a, b] in &p.struts {
        line(&mut strokes, a, b, 0.03, STRUT);
    }
    for ([a, b], look) in &p.cables {
        line(&mut strokes, a, b, if *look == CableLook::Slack { 0.006 } else { 0.012 }, cable_colour(*look));
    }
    for n in &p.nodes {
        line(&mut strokes, n, n, 0.06, STRUT);
    }
    for [a, b] in &p.contacts {
        line(&mut strokes, a, a, 0.04, CONTACT);
        line(&mut strokes, a, b, 0.01, CONTACT);
    }
    // the grid first (it lies under everything), then far before near
    strokes[grid..].sort_by(|x, y| y.depth.total_cmp(&x.depth));
    for s in &strokes {
        draw_stroke(s, (width, height), rgb);
    }
}

/// 1, 2 or 5 times a power of ten, the nearest at or below `x` (> 0).
fn nice_spacing(x: f64) -> f64 {
    let p = 10f64.powf(x.log10().floor());
    [5.0, 2.0, 1.0].into_iter().map(|m| m * p).find(|s| *s <= x).unwrap_or(p)
}

/// Paints a stroke with its edge blended over a pixel (coverage `half_width + 0.5 - distance`, at
/// most 1),
/// visiting only the pixels within reach of it: along its longer axis, the band around the line.
fn draw_stroke(s: &Stroke, (width, height): (usize, usize), rgb: &mut [u8]) {
    let reach = s.half_width + 1.0;
    let (dx, dy) = (s.b[0] - s.a[0], s.b[1] - s.a[1]);
    let len2 = dx * dx + dy * dy;
    // (x, y) in the frame, or (y, x) for a steep line: `major` runs along the longer axis
    let steep = dy.abs() > dx.abs();
    let (a, b) = if steep { ([s.a[1], s.a[0]], [s.b[1], s.b[0]]) } else { (s.a, s.b) };
    let (major_len, minor_len) = if steep { (height, width) } else { (width, height) };
    let slope = if b[0] != a[0] { (b[1] - a[1]) / (b[0] - a[0]) } else { 0.0 };
    // the band's half-height across the major axis
    let band = reach * (1.0 + slope * slope).sqrt();
    let m0 = (a[0].min(b[0]) - reach).floor().max(0.0);
    let m1 = (a[0].max(b[0]) + reach).ceil().min(major_len as f64 - 1.0);
    if !in_order(m0, m1) || minor_len == 0 {
        return;
    }
    let (lo_end, hi_end) = (a[1].min(b[1]) - reach, a[1].max(b[1]) + reach);
    // pixels at least this far (squared) from the line get nothing of it
    let outer2 = (s.half_width + 0.5) * (s.half_width + 0.5);
    for major in m0 as usize..=m1 as usize {
        let centre = a[1] + (major as f64 + 0.5 - a[0]) * slope;
        let n0 = (centre - band).max(lo_end).floor().max(0.0);
        let n1 = (centre + band).min(hi_end).ceil().min(minor_len as f64 - 1.0);
        if !in_order(n0, n1) {
            continue;
        }
        for minor in n0 as usize..=n1 as usize {
            let (x, y) = if steep { (minor, major) } else { (major, minor) };
            let (px, py) = (x as f64 + 0.5 - s.a[0], y as f64 + 0.5 - s.a[1]);
            let t = if len2 > 0.0 { ((px * dx + py * dy) / len2).clamp(0.0, 1.0) } else { 0.0 };
            let (ex, ey) = (px - t * dx, py - t * dy);
            let d2 = ex * ex + ey * ey;
            if d2 >= outer2 {
                continue;
            }
            let coverage = (s.half_width + 0.5 - d2.sqrt()).min(1.0);
            let at = 3 * (y * width + x);
            for (c, target) in rgb[at..at + 3].iter_mut().zip(s.colour) {
                // (a blend of two bytes is in [0, 255]: + 0.5 and truncation round it)
                *c = (*c as f64 + coverage * (target as f64 - *c as f64) + 0.5) as u8;
            }
        }
    }
}

/// `a <= b`, false when either is NaN (a stroke of a NaN state draws nothing).
fn in_order(a: f64, b: f64) -> bool {
    a <= b
}
