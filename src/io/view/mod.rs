//! The browser viewer: takes a model and its frames (body poses, cable tensions and rest lengths,
//! contact forces), gives a local HTTP server on 127.0.0.1 (`ViewServer`) that serves a page
//! compiled into the binary, the scene's geometry (`/scene.json`) and the frames as they come
//! (`/frames?from=K`, from a `FrameStore` that a scene's equilibrium, a bag or a running node
//! fills). Nothing is installed or downloaded at run time.
//!
//! Geometry: every model point is a vertex, then each rigid body's centre; a bar is drawn from
//! its end `.a` to its end `.b` (or between its points farthest apart along its axis), a rigid
//! body from its centre to each of its points, a cable along its route. A frame carries the
//! vertices in world coordinates (m), each cable's tension (N), rest length (m) and slack flag,
//! and each pressing contact's point and force on the body (N).

pub mod bag;
#[cfg(feature = "shm")]
pub mod live;
pub mod scene;

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use nalgebra::Vector3;
use serde::Serialize;

use crate::model::{BodyKind, CableId, Model, Pose};

/// The page (HTML), compiled in.
const PAGE_HTML: &str = include_str!("page/index.html");
/// The page's script, compiled in.
const PAGE_JS: &str = include_str!("page/viewer.js");

/// Why the viewer could not serve.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    /// The port is taken by another program.
    #[error("port {port} on 127.0.0.1 is in use by another program: pick another with --port (0 lets the system choose)")]
    PortInUse {
        /// The port asked for.
        port: u16,
    },
    /// The server could not start for another reason.
    #[error("cannot serve on 127.0.0.1:{port}: {reason}")]
    Serve {
        /// The port asked for.
        port: u16,
        /// Why.
        reason: String,
    },
}

/// Where a view's frames come from (the page says so and offers the controls that fit).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewSource {
    /// A scene's static equilibrium: one frame.
    Equilibrium,
    /// A scene's vibration modes, animated over the equilibrium.
    Modes,
    /// A recorded bag, replayed with a time slider.
    Bag,
    /// A running node, followed as it steps.
    Node,
}

/// What the drawing of a model is made of: which vertices the struts join, and where the rigid
/// bodies' centres go in the vertex list.
#[derive(Debug, Clone)]
pub struct ViewGeometry {
    /// Vertex pairs drawn as struts.
    struts: Vec<[usize; 2]>,
    /// Rigid bodies whose centre is a vertex (after the model's points), in vertex order.
    centred_bodies: Vec<usize>,
    /// Vertices of point masses.
    nodes: Vec<usize>,
}

impl ViewGeometry {
    /// The geometry of `model`'s drawing.
    pub fn new(model: &Model) -> Self {
        let mut struts = Vec::new();
        let mut centred_bodies = Vec::new();
        let mut nodes = Vec::new();
        let n_points = model.points.len();
        for (b, body) in model.bodies.iter().enumerate() {
            let own: Vec<usize> = (0..n_points).filter(|&p| model.points[p].body.0 == b).collect();
            match body.kind {
                BodyKind::Bar => {
                    let end =
                        |suffix: &str| own.iter().copied().find(|&p| model.points[p].name.ends_with(suffix));
                    let ends = match (end(".a"), end(".b")) {
                        (Some(a), Some(e)) => Some([a, e]),
                        _ => {
                            // the points farthest apart along the bar's axis (body z)
                            let z = |p: &usize| model.points[*p].local.z;
                            let lo = own.iter().copied().min_by(|a, b| z(a).total_cmp(&z(b)));
                            let hi = own.iter().copied().max_by(|a, b| z(a).total_cmp(&z(b)));
                            lo.zip(hi).filter(|(a, e)| a != e).map(|(a, e)| [a, e])
                        }
                    };
                    struts.extend(ends);
                }
                BodyKind::Rigid => {
                    let centre = n_points + centred_bodies.len();
                    centred_bodies.push(b);
                    struts.extend(
                        own.iter().filter(|&&p| model.points[p].local.norm() > 0.0).map(|&p| [centre, p]),
                    );
                }
                BodyKind::Node => nodes.extend(own.first().copied()),
                BodyKind::Fixed => {}
            }
        }
        Self { struts, centred_bodies, nodes }
    }

    /// Vertices of `model` at `poses`: every point, then each rigid body's centre (m, world).
    pub fn vertices(&self, model: &Model, poses: &[Pose]) -> Vec<[f64; 3]> {
        let mut out: Vec<[f64; 3]> =
            model.points.iter().map(|p| poses[p.body.0].transform_point(&p.local).into()).collect();
        out.extend(self.centred_bodies.iter().map(|&b| <[f64; 3]>::from(poses[b].position)));
        out
    }

    /// The scene description the page draws from (`/scene.json`): names, vertex count, struts,
    /// point masses, cable routes, pulleys, grounds, contact names, the up direction (against
    /// gravity, z without it) and a strut radius (the contact spheres' largest, else 1 % of the
    /// structure's size at `poses`).
    pub fn scene_json(&self, model: &Model, poses: &[Pose], source: ViewSource, label: &str) -> String {
        let vertices = self.vertices(model, poses);
        let (lo, hi) = bounds(&vertices);
        let size = (hi - lo).norm().max(1e-3);
        let radius = model.contact_spheres.iter().map(|s| s.radius).fold(0.0, f64::max);
        let up = if model.gravity.norm() > 0.0 { -model.gravity.normalize() } else { Vector3::z() };
        let cables: Vec<SceneCable> = (0..model.cables.len())
            .map(|c| SceneCable {
                name: model.cable_names[c].clone(),
                route: model.route(CableId(c)).iter().map(|p| p.0).collect(),
                tension_only: model.cables[c].tension_only,
            })
            .collect();
        let pulleys =
            cables.iter().flat_map(|c| c.route[1..c.route.len().saturating_sub(1)].iter().copied()).collect();
        let scene = SceneJson {
            name: &model.name,
            label,
            source,
            vertex_count: vertices.len(),
            struts: &self.struts,
            nodes: &self.nodes,
            cables,
            pulleys,
            grounds: model
                .grounds
                .iter()
                .map(|g| SceneGround { name: &g.name, normal: g.normal.into(), offset: g.offset })
                .collect(),
            contacts: model.contact_labels().map(|(p, g)| format!("{p} on {g}")).collect(),
            up: up.into(),
            centre: ((lo + hi) * 0.5).into(),
            size,
            strut_radius: if radius > 0.0 { radius } else { 0.01 * size },
            body_count: model.bodies.iter().filter(|b| b.kind != BodyKind::Fixed).count(),
            strut_count: self.struts.len(),
        };
        serde_json::to_string(&scene).unwrap_or_default()
    }
}

fn bounds(vertices: &[[f64; 3]]) -> (Vector3<f64>, Vector3<f64>) {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for v in vertices.iter().filter(|v| v.iter().all(|x| x.is_finite())) {
        let v = Vector3::from(*v);
        lo = lo.inf(&v);
        hi = hi.sup(&v);
    }
    if lo.x > hi.x {
        (Vector3::zeros(), Vector3::zeros())
    } else {
        (lo, hi)
    }
}

#[derive(Serialize)]
struct SceneCable {
    name: String,
    route: Vec<usize>,
    tension_only: bool,
}

#[derive(Serialize)]
struct SceneGround<'a> {
    name: &'a str,
    normal: [f64; 3],
    offset: f64,
}

#[derive(Serialize)]
struct SceneJson<'a> {
    name: &'a str,
    label: &'a str,
    source: ViewSource,
    vertex_count: usize,
    struts: &'a [[usize; 2]],
    nodes: &'a [usize],
    cables: Vec<SceneCable>,
    pulleys: Vec<usize>,
    grounds: Vec<SceneGround<'a>>,
    contacts: Vec<String>,
    up: [f64; 3],
    centre: [f64; 3],
    size: f64,
    strut_radius: f64,
    body_count: usize,
    strut_count: usize,
}

/// One frame as the page draws it.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Frame {
    /// Simulation time, s.
    pub time: f64,
    /// Steps taken (0 for a scene's equilibrium or mode frames).
    pub step: u64,
    /// Vertices, m, world (`ViewGeometry::vertices`).
    pub vertices: Vec<[f64; 3]>,
    /// Cable tensions, N, scene order.
    pub tension: Vec<f64>,
    /// Cable rest lengths, m.
    pub rest_length: Vec<f64>,
    /// Cable slack flags.
    pub slack: Vec<bool>,
    /// Pressing contacts: the contact point (m) and the force on the body (N), `[x, y, z, fx, fy, fz]`.
    pub contacts: Vec<[f64; 6]>,
}

impl Frame {
    /// The frame of `state`, evaluated in `ws` (`evaluate::evaluate_forces` or more): its
    /// vertices, cable tensions, rest lengths and slack flags (a tension-only cable carrying no
    /// tension), and its pressing contacts.
    pub fn of_state(
        model: &Model,
        geometry: &ViewGeometry,
        state: &crate::State,
        ws: &crate::evaluate::Workspace,
    ) -> Frame {
        Frame {
            time: state.time,
            step: 0,
            vertices: geometry.vertices(model, &state.poses),
            tension: ws.cables.iter().map(|c| c.tension).collect(),
            rest_length: state.rest_lengths.clone(),
            slack: ws
                .cables
                .iter()
                .zip(&model.cables)
                .map(|(c, m)| m.tension_only && c.tension <= 0.0)
                .collect(),
            contacts: ws
                .contacts
                .iter()
                .filter(|c| c.in_contact())
                .map(|c| {
                    let f = c.force();
                    [c.position.x, c.position.y, c.position.z, f.x, f.y, f.z]
                })
                .collect(),
        }
    }

    /// The frame as the page reads it: numbers rounded to 6 significant digits (sub-micrometre
    /// on a metre structure), non-finite ones as null, so a frame of a large structure stays
    /// small and never carries a NaN into the page.
    fn to_json(&self, seq: u64) -> String {
        use std::fmt::Write;
        let mut s = String::with_capacity(64 + 30 * self.vertices.len() + 40 * self.tension.len());
        let num = |s: &mut String, x: f64| {
            if x.is_finite() {
                let _ = write!(s, "{}", format!("{x:.5e}").parse::<f64>().unwrap_or(0.0));
            } else {
                s.push_str("null");
            }
        };
        let list = |s: &mut String, xs: &mut dyn Iterator<Item = f64>| {
            s.push('[');
            for (i, x) in xs.enumerate() {
                if i > 0 {
                    s.push(',');
                }
                num(s, x);
            }
            s.push(']');
        };
        let _ = write!(s, "{{\"seq\":{seq},\"step\":{},\"t\":", self.step);
        num(&mut s, self.time);
        s.push_str(",\"v\":");
        list(&mut s, &mut self.vertices.iter().flatten().copied());
        s.push_str(",\"T\":");
        list(&mut s, &mut self.tension.iter().copied());
        s.push_str(",\"L0\":");
        list(&mut s, &mut self.rest_length.iter().copied());
        s.push_str(",\"slack\":[");
        for (i, k) in self.slack.iter().enumerate() {
            s.push_str(if i > 0 { "," } else { "" });
            s.push(if *k { '1' } else { '0' });
        }
        s.push_str("],\"c\":");
        list(&mut s, &mut self.contacts.iter().flatten().copied());
        s.push('}');
        s
    }
}

/// What the page says of its source.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewStatus {
    /// `still` (an equilibrium), `animated` (modes), `recorded` (a bag: complete), `playing`,
    /// `paused` or `faulted` (a node, as it says), `waiting` (a node that sent nothing yet, or
    /// nothing for a while), `stopped` (a node that went away), `error`.
    pub state: String,
    /// A sentence for the page and the terminal (empty when there is nothing to say).
    pub message: String,
}

/// The frames a view holds, numbered in arrival order (`seq`), as JSON ready to send: all of a
/// bag's or a scene's, the newest `capacity` of a live node's.
pub struct FrameStore {
    inner: Mutex<StoreInner>,
}

struct StoreInner {
    first_seq: u64,
    frames: VecDeque<(f64, Arc<str>)>,
    capacity: usize,
    status: ViewStatus,
    largest_tension: f64,
    largest_force: f64,
}

impl FrameStore {
    /// An empty store keeping the newest `capacity` frames, with `status`.
    pub fn new(capacity: usize, status: ViewStatus) -> Self {
        Self {
            inner: Mutex::new(StoreInner {
                first_seq: 0,
                frames: VecDeque::new(),
                capacity: capacity.max(1),
                status,
                largest_tension: 0.0,
                largest_force: 0.0,
            }),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, StoreInner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Appends `frame` (the oldest frame goes when the store is full).
    pub fn push(&self, frame: &Frame) {
        let largest_tension = frame.tension.iter().copied().filter(|t| t.is_finite()).fold(0.0, f64::max);
        let largest_force = frame
            .contacts
            .iter()
            .map(|c| Vector3::new(c[3], c[4], c[5]).norm())
            .filter(|f| f.is_finite())
            .fold(0.0, f64::max);
        let mut inner = self.lock();
        let seq = inner.first_seq + inner.frames.len() as u64;
        let json: Arc<str> = frame.to_json(seq).into();
        if inner.frames.len() == inner.capacity {
            inner.frames.pop_front();
            inner.first_seq += 1;
        }
        inner.frames.push_back((frame.time, json));
        inner.largest_tension = inner.largest_tension.max(largest_tension);
        inner.largest_force = inner.largest_force.max(largest_force);
    }

    /// Sets what the page says of the source.
    pub fn set_status(&self, state: &str, message: &str) {
        let mut inner = self.lock();
        if inner.status.state != state || inner.status.message != message {
            inner.status = ViewStatus { state: state.into(), message: message.into() };
        }
    }

    /// The current status.
    pub fn status(&self) -> ViewStatus {
        self.lock().status.clone()
    }

    /// Frames held.
    pub fn len(&self) -> usize {
        self.lock().frames.len()
    }

    /// Whether no frame is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The `/frames` answer: the status, the numbers the page scales by (largest tension and
    /// contact force so far, the held time span) and up to `max` frames from `from` on (from
    /// the oldest held when `from` is older).
    fn frames_json(&self, from: u64, max: usize) -> String {
        let inner = self.lock();
        let start = from.max(inner.first_seq);
        let skip = (start - inner.first_seq) as usize;
        let mut out = String::new();
        let (t0, t1) = match (inner.frames.front(), inner.frames.back()) {
            (Some(a), Some(b)) => (a.0, b.0),
            _ => (0.0, 0.0),
        };
        let status = serde_json::to_string(&inner.status).unwrap_or_default();
        let finite = |x: f64| if x.is_finite() { x } else { 0.0 };
        out.push_str(&format!(
            "{{\"status\":{status},\"first\":{},\"next\":{},\"time_span\":[{},{}],\"largest_tension\":{},\"largest_force\":{},\"frames\":[",
            inner.first_seq,
            inner.first_seq + inner.frames.len() as u64,
            finite(t0),
            finite(t1),
            inner.largest_tension,
            inner.largest_force
        ));
        for (i, (_, f)) in inner.frames.iter().skip(skip).take(max).enumerate() {
            if i > 0 {
                out.push(',');
            }
            out.push_str(f);
        }
        out.push_str("]}");
        out
    }
}

/// The viewer's HTTP server on 127.0.0.1.
pub struct ViewServer {
    server: tiny_http::Server,
    scene: Arc<str>,
    store: Arc<FrameStore>,
}

/// Most frames one `/frames` answer carries.
const FRAMES_PER_ANSWER: usize = 2000;

impl ViewServer {
    /// Binds 127.0.0.1:`port` (0: a free port the system chooses) for the scene description
    /// `scene_json` (`ViewGeometry::scene_json`) and the frames of `store`.
    pub fn bind(port: u16, scene_json: String, store: Arc<FrameStore>) -> Result<Self, ViewError> {
        let server = tiny_http::Server::http(("127.0.0.1", port)).map_err(|e| {
            let in_use =
                e.downcast_ref::<std::io::Error>().is_some_and(|e| e.kind() == std::io::ErrorKind::AddrInUse);
            if in_use {
                ViewError::PortInUse { port }
            } else {
                ViewError::Serve { port, reason: e.to_string() }
            }
        })?;
        Ok(Self { server, scene: scene_json.into(), store })
    }

    /// The page's address, `http://127.0.0.1:PORT/`.
    pub fn url(&self) -> String {
        match self.server.server_addr().to_ip() {
            Some(addr) => format!("http://{addr}/"),
            None => "http://127.0.0.1/".into(),
        }
    }

    /// Answers requests until `stop` is set (checked every 100 ms).
    pub fn serve_until(&self, stop: &AtomicBool) {
        while !stop.load(Ordering::Relaxed) {
            match self.server.recv_timeout(Duration::from_millis(100)) {
                Ok(Some(request)) => self.answer(request),
                Ok(None) => {}
                Err(_) => std::thread::sleep(Duration::from_millis(10)),
            }
        }
    }

    fn answer(&self, request: tiny_http::Request) {
        let url = request.url().to_string();
        let (path, query) = url.split_once('?').unwrap_or((&url, ""));
        let param = |key: &str| -> Option<u64> {
            query.split('&').filter_map(|kv| kv.split_once('=')).find(|(k, _)| *k == key)?.1.parse().ok()
        };
        let (body, kind, code): (String, &str, u16) = match (request.method(), path) {
            (tiny_http::Method::Get, "/" | "/index.html") => {
                (PAGE_HTML.into(), "text/html; charset=utf-8", 200)
            }
            (tiny_http::Method::Get, "/viewer.js") => (PAGE_JS.into(), "text/javascript; charset=utf-8", 200),
            (tiny_http::Method::Get, "/scene.json") => (self.scene.to_string(), "application/json", 200),
            (tiny_http::Method::Get, "/frames") => {
                let max =
                    param("max").map_or(FRAMES_PER_ANSWER, |m| (m as usize).clamp(1, FRAMES_PER_ANSWER));
                (self.store.frames_json(param("from").unwrap_or(0), max), "application/json", 200)
            }
            (tiny_http::Method::Get, "/favicon.ico") => (String::new(), "image/x-icon", 204),
            _ => (format!("no such page: {path}"), "text/plain; charset=utf-8", 404),
        };
        let header = tiny_http::Header::from_bytes(&b"Content-Type"[..], kind.as_bytes());
        let no_cache = tiny_http::Header::from_bytes(&b"Cache-Control"[..], &b"no-store"[..]);
        let mut response = tiny_http::Response::from_string(body).with_status_code(code);
        for h in [header, no_cache].into_iter().flatten() {
            response.add_header(h);
        }
        // a browser that went away mid-answer is no error of ours
        let _ = request.respond(response);
    }
}
