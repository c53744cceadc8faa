//! Parametric scene generators: take a few numbers, give a `SceneSpec` (which `tensegrity generate`
//! writes as TOML): the regular n-strut prism, an N-stage tower of stacked prisms with clustered
//! side cables, a planar clustered T-bar (and its pin-jointed form), the elastic Atwood machine,
//! and the six-bar robot on the ground; the prism and the T-bar also in nodal (finite-element)
//! form (`nodal_struts`).
//!
//! Prism geometry (docs/architecture.md, "What the tests stand on"): bottom node i at angle `2 pi i / n` and height 0, top node i at
//! `2 pi i / n + alpha` and height `h`, twist `alpha = pi/2 + pi/n`; bars bottom i to top i, side
//! strings bottom i to top i-1, rings. Its self-stress has force densities `q_bar = -q_side` and
//! `q_ring = q_side / (2 sin(pi/n))`. Bars stand on pins (their bottom ends are pinned to the
//! ground), so the bottom ring is not needed; only the side strings get a prestress target and form
//! finding determines the rest.

use std::f64::consts::PI;

use super::{
    ActuatorSpec, BodyKindSpec, BodySpec, CableSpec, DeploymentSpec, GroundSpec, JointKindSpec, JointSpec,
    MassMatrixSpec, PointSpec, RampSpec, SceneSpec,
};

/// Parameters of the regular n-strut prism.
#[derive(Debug, Clone, PartialEq)]
pub struct PrismParams {
    /// Number of struts (>= 3).
    pub n: usize,
    /// Radius of both rings, m.
    pub radius: f64,
    /// Height, m.
    pub height: f64,
    /// Mass of each bar, kg.
    pub bar_mass: f64,
    /// Axial stiffness of every cable, N.
    pub ea: f64,
    /// Target tension of each side string, N.
    pub side_prestress: f64,
    /// Replace the top ring's n strings by one closed clustered cable through pulleys at the top
    /// nodes (anchored at top node 0), driven by an actuator.
    pub cluster_top_ring: bool,
    /// Damping ratio of every cable.
    pub damping_ratio: f64,
    /// Fraction by which the deployment schedule shortens the clustered ring (0 = no schedule).
    pub deploy_shortening: f64,
    /// The nodal (finite-element) form: every bar an elastic member of this EA (N) between two
    /// nodes (`nodal_struts`). `None`: rigid bars.
    pub nodal_strut_ea: Option<f64>,
    /// How the nodal form's members carry their mass (lumped or consistent); ignored for
    /// rigid bars.
    pub nodal_mass_matrix: MassMatrixSpec,
}

impl Default for PrismParams {
    fn default() -> Self {
        Self {
            n: 3,
            radius: 1.0,
            height: 1.5,
            bar_mass: 2.0,
            ea: 5e4,
            side_prestress: 100.0,
            cluster_top_ring: true,
            damping_ratio: 0.05,
            deploy_shortening: 0.1,
            nodal_strut_ea: None,
            nodal_mass_matrix: MassMatrixSpec::Lumped,
        }
    }
}

fn bar(name: String, mass: f64, a: [f64; 3], b: [f64; 3]) -> BodySpec {
    BodySpec { mass: Some(mass), ends: Some([a, b]), ..BodySpec::new(&name, BodyKindSpec::Bar) }
}

/// A joint of `kind` holding point `a` on point `b` (or, without `b`, where `a` starts).
fn joint(kind: JointKindSpec, a: &str, b: Option<&str>) -> JointSpec {
    JointSpec {
        kind,
        a: a.into(),
        b: b.map(Into::into),
        at: None,
        direction: None,
        normal: None,
        axis: None,
        damping: None,
    }
}

fn cable(name: String, route: Vec<String>, ea: f64, zeta: f64) -> CableSpec {
    CableSpec {
        name,
        route,
        ea,
        damping: None,
        damping_ratio: if zeta > 0.0 { Some(zeta) } else { None },
        rest_length: None,
        prestress: None,
        force_density: None,
        tension_only: true,
        pulley_friction: None,
        winch_end: None,
    }
}

fn ring_point(radius: f64, angle: f64, z: f64) -> [f64; 3] {
    [radius * angle.cos(), radius * angle.sin(), z]
}

/// Twist of the regular n-prism, `pi/2 + pi/n` (rad).
pub fn prism_twist(n: usize) -> f64 {
    PI / 2.0 + PI / n as f64
}

/// The regular n-prism on pinned supports; see the module docs.
pub fn prism(p: &PrismParams) -> SceneSpec {
    let mut spec = tower(&TowerParams {
        n: p.n,
        stages: 1,
        radius: p.radius,
        stage_height: p.height,
        bar_mass: p.bar_mass,
        ea: p.ea,
        side_prestress: p.side_prestress,
        cluster_sides: false,
        cluster_per_stage: false,
        cluster_top_ring: p.cluster_top_ring,
        damping_ratio: p.damping_ratio,
        deploy_shortening: p.deploy_shortening,
    });
    if let Some(ea) = p.nodal_strut_ea {
        nodal_struts(&mut spec, ea, p.nodal_mass_matrix);
        spec.name = format!("{}_nodal", spec.name);
        spec.description = format!(
            "{} (nodal: struts as elastic members of EA {ea} N between point masses)",
            spec.description
        );
    }
    spec
}

/// Writes each cable's `damping_ratio` of `spec` as the damping coefficient `c` (N s/m) it gives
/// there, Rayleigh's `beta` part left out: a ratio's `c = 2 zeta sqrt((EA / L0) m_eff)` depends on
/// the masses of the bodies on the route, which the nodal form moves onto nodes, and the nodal
/// form must keep the rigid scene's dashpots to converge to it. A spec that does not build is
/// left as it is (building the nodal form then says why).
fn keep_dashpots(spec: &mut SceneSpec) {
    let Ok(model) = super::build_model(spec, "<generated>", None) else { return };
    for cable in spec.cables.iter_mut().filter(|c| c.damping_ratio.is_some()) {
        let Some(c) = model.cable_names.iter().position(|n| *n == cable.name) else { continue };
        let material = model.cables[c].axial_stiffness / model.initial_rest_lengths[c];
        cable.damping_ratio = None;
        cable.damping = Some(model.cables[c].damping - model.rayleigh.beta * material);
    }
}

/// Turns `spec` into its nodal (finite-element) form: every bar `B` becomes the nodes `B_a` and
/// `B_b` at its ends and an elastic member `B` between them of axial stiffness `strut_ea` (N),
/// the bar's mass on the two nodes as `mass_matrix` says, its axial force whatever makes the
/// initial geometry an equilibrium (`form_find`); references to `B.a` and `B.b` (routes,
/// joints, ramps) move to the nodes, and cables given a damping ratio keep the dashpot it gives
/// in `spec` (`keep_dashpots`). Bar ends that a ball joint ties together (`a` and `b` both bar
/// ends) become one node, named after the joint's `b` end, and the joint goes: the members meet
/// there as pin-jointed bars do in a finite-element model. A bar with other points keeps them
/// nowhere: only its ends are carried over. Lumped mass gives a strut the transverse inertia of
/// its two end masses, `m l^2 / 4` about its middle, where the uniform rigid bar has
/// `m l^2 / 12`; the consistent mass matrix gives it exactly `m l^2 / 12`.
pub fn nodal_struts(spec: &mut SceneSpec, strut_ea: f64, mass_matrix: MassMatrixSpec) {
    keep_dashpots(spec);
    let bar_ends: std::collections::BTreeSet<String> = spec
        .bodies
        .iter()
        .filter(|b| b.kind == BodyKindSpec::Bar)
        .flat_map(|b| [format!("{}.a", b.name), format!("{}.b", b.name)])
        .collect();
    // bar ends that ball joints tie together become one node, the one of the joint's `b` end
    let mut renamed = std::collections::BTreeMap::new();
    for b in &spec.bodies {
        if b.kind == BodyKindSpec::Bar {
            for end in ["a", "b"] {
                renamed.insert(format!("{}.{end}", b.name), format!("{}_{end}", b.name));
            }
        }
    }
    let tied = |j: &JointSpec| match (&j.kind, &j.b) {
        (JointKindSpec::Ball, Some(b)) if bar_ends.contains(&j.a) && bar_ends.contains(b) => Some(b.clone()),
        _ => None,
    };
    for j in &spec.joints {
        if let Some(b) = tied(j) {
            let (keep, gone) = (renamed[&b].clone(), renamed[&j.a].clone());
            renamed.values_mut().filter(|n| **n == gone).for_each(|n| *n = keep.clone());
        }
    }
    spec.joints.retain(|j| tied(j).is_none());
    let mut bodies = Vec::new();
    let mut placed = std::collections::BTreeSet::new();
    for b in std::mem::take(&mut spec.bodies) {
        let (BodyKindSpec::Bar, Some([a, e])) = (b.kind, b.ends) else {
            bodies.push(b);
            continue;
        };
        for (end, at) in [("a", a), ("b", e)] {
            let node = renamed[&format!("{}.{end}", b.name)].clone();
            if placed.insert(node.clone()) {
                bodies.push(BodySpec { position: Some(at), ..BodySpec::new(&node, BodyKindSpec::Node) });
            }
        }
        spec.members.push(super::MemberSpec {
            name: b.name.clone(),
            ends: [renamed[&format!("{}.a", b.name)].clone(), renamed[&format!("{}.b", b.name)].clone()],
            ea: strut_ea,
            damping: None,
            damping_ratio: None,
            rest_length: None,
            force: None,
            form_find: true,
            mass: b.mass,
            mass_matrix,
            bending_stiffness: None,
            buckling_load: None,
        });
    }
    spec.bodies = bodies;
    let rename = |p: &mut String| {
        if let Some(n) = renamed.get(p.as_str()) {
            *p = n.clone();
        }
    };
    for c in &mut spec.cables {
        c.route.iter_mut().for_each(rename);
    }
    for j in &mut spec.joints {
        rename(&mut j.a);
        if let Some(b) = &mut j.b {
            rename(b);
        }
    }
}

/// Parameters of a tower of stacked prisms.
#[derive(Debug, Clone, PartialEq)]
pub struct TowerParams {
    /// Struts per stage (>= 3).
    pub n: usize,
    /// Number of stages (>= 1).
    pub stages: usize,
    /// Ring radius, m.
    pub radius: f64,
    /// Height of each stage, m.
    pub stage_height: f64,
    /// Mass of each bar, kg.
    pub bar_mass: f64,
    /// Axial stiffness of every cable, N.
    pub ea: f64,
    /// Target tension of the side strings, N.
    pub side_prestress: f64,
    /// Cluster the side strings that continue from stage to stage into n helical cables through
    /// pulleys at the stage joints, each driven by an actuator.
    pub cluster_sides: bool,
    /// Without `cluster_sides`: run each stage's side strings as one clustered cable (bottom 0,
    /// top n-1, down bar n-1, top n-2, ..., top 0: pulleys at the bar ends, the legs along the
    /// bars keep their length), coupling the stage's bars only.
    pub cluster_per_stage: bool,
    /// Cluster the top ring into one closed cable, driven by an actuator.
    pub cluster_top_ring: bool,
    /// Damping ratio of every cable.
    pub damping_ratio: f64,
    /// Fraction by which the schedule shortens the actuated cables.
    pub deploy_shortening: f64,
}

impl Default for TowerParams {
    fn default() -> Self {
        Self {
            n: 3,
            stages: 3,
            radius: 1.0,
            stage_height: 1.2,
            bar_mass: 2.0,
            ea: 5e4,
            side_prestress: 100.0,
            cluster_sides: true,
            cluster_per_stage: false,
            cluster_top_ring: false,
            damping_ratio: 0.05,
            deploy_shortening: 0.05,
        }
    }
}

/// A tower of `stages` regular prisms stacked with the same twist: node `i` of level `l` at height
/// `l h` and angle `2 pi i / n + l alpha`; the bars of consecutive stages are joined by ball joints at
/// the shared nodes and the bottom bars are pinned to the ground. Every stage carries the prism's
/// self-stress, so intermediate rings carry twice the top ring's force density.
pub fn tower(p: &TowerParams) -> SceneSpec {
    let (n, s) = (p.n, p.stages);
    let alpha = prism_twist(n);
    let node = |level: usize, i: usize| {
        ring_point(
            p.radius,
            2.0 * PI * i as f64 / n as f64 + level as f64 * alpha,
            level as f64 * p.stage_height,
        )
    };
    // name of the point at level l, index i: the bottom end of the bar above, or the top end of the
    // last stage's bar
    let point = |level: usize, i: usize| {
        let i = i % n;
        if level < s {
            format!("bar{level}_{i}.a")
        } else {
            format!("bar{}_{i}.b", s - 1)
        }
    };
    let mut spec = SceneSpec {
        name: if s == 1 { format!("prism{n}") } else { format!("tower{n}x{s}") },
        description: if s == 1 {
            format!(
                "Regular {n}-strut prism on pinned supports, side strings prestressed to {} N",
                p.side_prestress
            )
        } else {
            format!(
                "Tower of {s} stacked {n}-strut prisms, clustered side cables, prestress {} N",
                p.side_prestress
            )
        },
        ..Default::default()
    };
    for l in 0..s {
        for i in 0..n {
            spec.bodies.push(bar(format!("bar{l}_{i}"), p.bar_mass, node(l, i), node(l + 1, i)));
        }
    }
    for i in 0..n {
        spec.joints.push(joint(JointKindSpec::Pin, &point(0, i), None));
    }
    for l in 1..s {
        for i in 0..n {
            spec.joints.push(joint(JointKindSpec::Ball, &format!("bar{}_{i}.b", l - 1), Some(&point(l, i))));
        }
    }
    let mut actuated = Vec::new();
    // side strings: bottom i to top i-1 in every stage
    if p.cluster_sides && s > 1 {
        for i in 0..n {
            let route = (0..=s).map(|l| point(l, i + n * s - l)).collect();
            let mut c = cable(format!("side{i}"), route, p.ea, p.damping_ratio);
            c.prestress = Some(p.side_prestress);
            actuated.push(c.name.clone());
            spec.cables.push(c);
        }
    } else if p.cluster_per_stage {
        for l in 0..s {
            let mut route = vec![point(l, 0)];
            for i in (0..n).rev() {
                route.push(format!("bar{l}_{i}.b"));
                if i > 0 {
                    route.push(point(l, i));
                }
            }
            let mut c = cable(format!("vertical{l}"), route, p.ea, p.damping_ratio);
            c.prestress = Some(p.side_prestress);
            spec.cables.push(c);
        }
    } else {
        for l in 0..s {
            for i in 0..n {
                let name = if s == 1 { format!("side{i}") } else { format!("side{l}_{i}") };
                let mut c = cable(name, vec![point(l, i), point(l + 1, i + n - 1)], p.ea, p.damping_ratio);
                c.prestress = Some(p.side_prestress);
                spec.cables.push(c);
            }
        }
    }
    // rings at every level above the ground
    for l in 1..=s {
        if l == s && p.cluster_top_ring {
            let mut route: Vec<String> = (0..n).map(|i| point(l, i)).collect();
            route.push(point(l, 0));
            let c = cable("ring".into(), route, p.ea, p.damping_ratio);
            actuated.push(c.name.clone());
            spec.cables.push(c);
        } else {
            for i in 0..n {
                let name = if s == 1 { format!("ring{i}") } else { format!("ring{l}_{i}") };
                spec.cables.push(cable(name, vec![point(l, i), point(l, i + 1)], p.ea, p.damping_ratio));
            }
        }
    }
    // the schedule needs the form-found rest lengths; parameters that make an invalid scene
    // (e.g. a clustered ring longer than a route may be) give it without one, and building it
    // then says why
    let built = if p.deploy_shortening > 0.0 && !actuated.is_empty() {
        super::build_model(&spec, "<generated>", None).ok()
    } else {
        None
    };
    if let Some(scene_model) = built {
        let mut ramps = Vec::new();
        for name in actuated {
            let c = scene_model.cable_id(&name).expect("generated cable");
            let l0 = scene_model.initial_rest_lengths[c.0];
            let target = l0 * (1.0 - p.deploy_shortening);
            spec.actuators.push(ActuatorSpec {
                name: format!("{name}_winch"),
                cable: name.clone(),
                min_rest_length: round6(0.5 * l0),
                max_rest_length: round6(1.2 * l0),
                max_rate: round6(l0),
                command_delay: None,
                command_delay_s: None,
                winch: None,
            });
            ramps.push(RampSpec {
                actuator: format!("{name}_winch"),
                start: 0.0,
                duration: 1.0,
                rest_length: round6(target),
            });
        }
        spec.deployment = Some(DeploymentSpec { steps: 40, ramps });
    }
    spec
}

fn round6(x: f64) -> f64 {
    (x * 1e6).round() / 1e6
}

/// Parameters of the planar clustered T-bar.
#[derive(Debug, Clone, PartialEq)]
pub struct TbarParams {
    /// Half-length of the vertical bar (the mast), m.
    pub half_height: f64,
    /// Half-length of the horizontal bar, m.
    pub half_width: f64,
    /// Horizontal distance of the guy anchors from the mast foot, m.
    pub anchor_distance: f64,
    /// Bar masses, kg (of the whole mast and the whole cross bar).
    pub bar_mass: f64,
    /// Axial stiffness of every cable, N.
    pub ea: f64,
    /// Target tension of the sliding upper cable, N (the rigid hub only: with `hinged_hub` the
    /// two upper strings carry what the other targets leave them).
    pub prestress: f64,
    /// Target tension of the two lower strings, N.
    pub lower_prestress: f64,
    /// Target tension of the two guys, N.
    pub guy_prestress: f64,
    /// Damping ratio of every cable.
    pub damping_ratio: f64,
    /// Fraction by which the schedule shortens the left lower string.
    pub deploy_shortening: f64,
    /// Skelton's pin-jointed T-bar: the mast and the cross bar each as two half-bars, all four
    /// joined at the hub by ball joints, and the two upper strings separate (a sliding upper
    /// cable leaves a hinged hub a mechanism: the lower triangle turns about the foot, kinking
    /// the mast, and changes no string's length to first order). The rigid twin of the nodal
    /// form.
    pub hinged_hub: bool,
    /// The nodal (finite-element) form of the hinged T-bar (implies `hinged_hub`): the four
    /// half-bars as elastic members of this EA (N) between five point masses (`nodal_struts`).
    pub nodal_strut_ea: Option<f64>,
    /// How the nodal form's members carry their mass (lumped or consistent).
    pub nodal_mass_matrix: MassMatrixSpec,
}

impl Default for TbarParams {
    fn default() -> Self {
        Self {
            half_height: 1.0,
            half_width: 0.6,
            anchor_distance: 1.5,
            bar_mass: 1.0,
            ea: 2e4,
            prestress: 50.0,
            lower_prestress: 50.0,
            guy_prestress: 80.0,
            damping_ratio: 0.05,
            deploy_shortening: 0.1,
            hinged_hub: false,
            nodal_strut_ea: None,
            nodal_mass_matrix: MassMatrixSpec::Lumped,
        }
    }
}

/// Planar T-bar (Skelton's unit) in the xy plane, y up, gravity -y: a vertical mast pinned at its
/// foot and held by two guys from its top to ground anchors, a horizontal bar joined at its centre
/// to the mast's centre, and a diamond of strings: the two lower strings (bar end to mast foot) and
/// the two upper strings (bar end, mast top, other bar end) as one sliding cable through a pulley at
/// the mast top. An actuator hauls in the left lower string, tilting the cross bar so that the upper
/// cable slides over the mast top. The scene's symmetric tensions are independent self-stress
/// states, so every cable gets a prestress target.
///
/// With `hinged_hub` (or `nodal_strut_ea`) the mast and the cross bar are two half-bars each
/// (`mast_lower`, `mast_upper`, `cross_left`, `cross_right`, each from the hub outwards but the
/// lower mast, which runs foot to hub), ball-jointed at the hub, and the upper strings are two
/// (`upper_left`, `upper_right`) whose tensions equilibrium fixes from the lower strings' and the
/// guys' targets. The nodal form makes the hub one node (`mast_lower_b`).
pub fn tbar(p: &TbarParams) -> SceneSpec {
    let h = p.half_height;
    let w = p.half_width;
    let mut ground = BodySpec::new("ground", BodyKindSpec::Fixed);
    ground.points.insert("left".into(), PointSpec::Local([-p.anchor_distance, 0.0, 0.0]));
    ground.points.insert("right".into(), PointSpec::Local([p.anchor_distance, 0.0, 0.0]));
    let string = |name: &str, route: &[&str], t: Option<f64>| {
        let mut c = cable(name.into(), route.iter().map(|s| s.to_string()).collect(), p.ea, p.damping_ratio);
        c.prestress = t;
        c
    };
    let hinged = p.hinged_hub || p.nodal_strut_ea.is_some();
    let (bodies, joints, upper, [left, right, foot, top]) = if hinged {
        let half = 0.5 * p.bar_mass;
        let hub = [0.0, h, 0.0];
        (
            vec![
                ground,
                bar("mast_lower".into(), half, [0.0, 0.0, 0.0], hub),
                bar("mast_upper".into(), half, hub, [0.0, 2.0 * h, 0.0]),
                bar("cross_left".into(), half, hub, [-w, h, 0.0]),
                bar("cross_right".into(), half, hub, [w, h, 0.0]),
            ],
            vec![
                joint(JointKindSpec::Pin, "mast_lower.a", None),
                joint(JointKindSpec::Ball, "mast_upper.a", Some("mast_lower.b")),
                joint(JointKindSpec::Ball, "cross_left.a", Some("mast_lower.b")),
                joint(JointKindSpec::Ball, "cross_right.a", Some("mast_lower.b")),
            ],
            vec![
                string("upper_left", &["cross_left.b", "mast_upper.b"], None),
                string("upper_right", &["mast_upper.b", "cross_right.b"], None),
            ],
            ["cross_left.b", "cross_right.b", "mast_lower.a", "mast_upper.b"],
        )
    } else {
        let mut mast = bar("mast".into(), p.bar_mass, [0.0, 0.0, 0.0], [0.0, 2.0 * h, 0.0]);
        mast.points.insert("mid".into(), PointSpec::Along(0.5));
        let cross = bar("cross".into(), p.bar_mass, [-w, h, 0.0], [w, h, 0.0]);
        (
            vec![ground, mast, cross],
            vec![
                joint(JointKindSpec::Pin, "mast.a", None),
                joint(JointKindSpec::Ball, "cross", Some("mast.mid")),
            ],
            vec![string("upper", &["cross.a", "mast.b", "cross.b"], Some(p.prestress))],
            ["cross.a", "cross.b", "mast.a", "mast.b"],
        )
    };
    let (name, description) = if hinged {
        ("tbar_hinged", "Planar T-bar, pin-jointed at the hub: four half-bars and six strings")
    } else {
        ("tbar", "Planar clustered T-bar: the two upper strings are one sliding cable over the mast top")
    };
    let mut cables = upper;
    cables.extend([
        string("lower_left", &[left, foot], Some(p.lower_prestress)),
        string("lower_right", &[right, foot], Some(p.lower_prestress)),
        string("guy_left", &[top, "ground.left"], Some(p.guy_prestress)),
        string("guy_right", &[top, "ground.right"], Some(p.guy_prestress)),
    ]);
    let mut spec = SceneSpec {
        name: name.into(),
        description: description.into(),
        gravity: [0.0, -9.81, 0.0],
        planar: true,
        bodies,
        joints,
        cables,
        ..Default::default()
    };
    // the winch hauls in the left lower string: the cross bar tilts and the upper cable slides
    // over the mast top (a symmetric pull would only change tensions: the bars are rigid); an
    // invalid scene is given without the schedule, and building it says why
    let built =
        if p.deploy_shortening > 0.0 { super::build_model(&spec, "<generated>", None).ok() } else { None };
    if let Some(model) = built {
        let lower = model.cable_names.iter().position(|n| n == "lower_left").expect("the lower string");
        let l0 = model.initial_rest_lengths[lower];
        spec.actuators.push(ActuatorSpec {
            name: "lower_winch".into(),
            cable: "lower_left".into(),
            min_rest_length: round6(0.5 * l0),
            max_rest_length: round6(1.2 * l0),
            max_rate: round6(l0),
            command_delay: None,
            command_delay_s: None,
            winch: None,
        });
        spec.deployment = Some(DeploymentSpec {
            steps: 40,
            ramps: vec![RampSpec {
                actuator: "lower_winch".into(),
                start: 0.0,
                duration: 1.0,
                rest_length: round6(l0 * (1.0 - p.deploy_shortening)),
            }],
        });
    }
    if let Some(ea) = p.nodal_strut_ea {
        nodal_struts(&mut spec, ea, p.nodal_mass_matrix);
        spec.name = "tbar_nodal".into();
        spec.description = format!(
            "Planar T-bar in nodal form: four half-bars as elastic members of EA {ea} N meeting at a hub node, six strings"
        );
    }
    spec
}

/// Parameters of the elastic Atwood machine.
#[derive(Debug, Clone, PartialEq)]
pub struct AtwoodParams {
    /// First mass, kg.
    pub m1: f64,
    /// Second mass, kg.
    pub m2: f64,
    /// Cable stiffness `k = EA/L0`, N/m.
    pub stiffness: f64,
    /// Length of each hanging segment, m.
    pub drop: f64,
    /// Distance between the two fixed pulleys, m.
    pub pulley_spacing: f64,
    /// Initial stretch `L - L0`, m (0 = just taut; negative = slack).
    pub initial_stretch: f64,
}

impl Default for AtwoodParams {
    fn default() -> Self {
        Self { m1: 2.0, m2: 1.0, stiffness: 1000.0, drop: 1.0, pulley_spacing: 0.2, initial_stretch: 0.0 }
    }
}

/// Elastic Atwood machine: two point masses hanging from one cable over two fixed pulleys
/// (gravity -z); rest length `L0 = L - stretch` and `EA = k L0`.
pub fn atwood(p: &AtwoodParams) -> SceneSpec {
    let half = p.pulley_spacing / 2.0;
    let mut ceiling = BodySpec::new("ceiling", BodyKindSpec::Fixed);
    ceiling.points.insert("left".into(), PointSpec::Local([-half, 0.0, 0.0]));
    ceiling.points.insert("right".into(), PointSpec::Local([half, 0.0, 0.0]));
    let mass = |name: &str, m: f64, x: f64| BodySpec {
        mass: Some(m),
        position: Some([x, 0.0, -p.drop]),
        ..BodySpec::new(name, BodyKindSpec::Node)
    };
    let length = 2.0 * p.drop + p.pulley_spacing;
    let rest = length - p.initial_stretch;
    SceneSpec {
        name: "atwood".into(),
        description: format!(
            "Elastic Atwood machine: m1 = {} kg, m2 = {} kg, k = EA/L0 = {} N/m",
            p.m1, p.m2, p.stiffness
        ),
        gravity: [0.0, 0.0, -9.81],
        bodies: vec![ceiling, mass("m1", p.m1, -half), mass("m2", p.m2, half)],
        cables: vec![CableSpec {
            name: "rope".into(),
            route: vec!["m1".into(), "ceiling.left".into(), "ceiling.right".into(), "m2".into()],
            ea: p.stiffness * rest,
            damping: None,
            damping_ratio: None,
            rest_length: Some(rest),
            prestress: None,
            force_density: None,
            tension_only: true,
            pulley_friction: None,
            winch_end: None,
        }],
        ..Default::default()
    }
}

/// Parameters of the six-bar robot (`sixbar`).
#[derive(Debug, Clone, PartialEq)]
pub struct SixbarParams {
    /// Strut length, m.
    pub strut_length: f64,
    /// Mass of each strut, kg.
    pub bar_mass: f64,
    /// Axial stiffness of every cable, N.
    pub ea: f64,
    /// Tension of every cable in the weightless self-stress, N (sets the rest lengths).
    pub prestress: f64,
    /// Damping ratio of every cable.
    pub damping_ratio: f64,
    /// Radius of the struts' contact capsules, m.
    pub contact_radius: f64,
    /// Friction coefficient of the ground.
    pub mu: f64,
    /// Rest length the roll winch hauls its cable in to, as a fraction of its length.
    pub roll_fraction: f64,
    /// Duration of that haul, s.
    pub roll_duration: f64,
    /// A winch on every cable (`w_` and the cable's name: `w_c00` ... `w_c23`), for a
    /// controller that rolls the robot where it wants, and no schedule; else the one
    /// `roll_winch` and its haul.
    pub all_winches: bool,
    /// Robots on the one ground, on a square grid `ROBOT_SPACING` apart (at least 1; rows of
    /// `ceil(sqrt(robots))` along x, then on along y); from 2 on,
    /// each robot's bodies, cables, actuators and ramps carry the prefix `rK_` (`r0_x0`,
    /// `r1_roll_winch`), for measuring cost against size.
    pub robots: usize,
}

/// Distance between neighbouring robots of a generated fleet (`SixbarParams::robots`), m: far
/// enough that a robot rolling one face does not reach the next.
pub const ROBOT_SPACING: f64 = 3.0;

impl Default for SixbarParams {
    fn default() -> Self {
        Self {
            strut_length: 1.0,
            bar_mass: 0.3,
            ea: 2e4,
            prestress: 20.0,
            damping_ratio: 0.05,
            contact_radius: 0.02,
            mu: 0.8,
            roll_fraction: 0.57,
            roll_duration: 2.0,
            all_winches: false,
            robots: 1,
        }
    }
}

/// The six-bar tensegrity robot (the expanded octahedron): three pairs of parallel struts of
/// length `L` along x, y and z, each pair `L / 2` apart (`(+-L/2, 0, +-L/4)` and its cyclic
/// permutations), and 24 cables of length `sqrt(6) L / 4` joining each strut end to the four
/// nearest ends of the other pairs. With equal cable tensions `T` this is a self-equilibrium
/// (strut to cable length `sqrt(8/3)`); the rest lengths are those of tension `T`. The structure
/// is turned so that the closed cable triangle on the ends towards `(1, 1, 1)` faces down, and
/// stands on it on a level `[[grounds]]` with friction, its struts capsules of radius
/// `contact_radius`. One actuator (`roll_winch`) on an edge of that bottom triangle hauls the cable
/// in: the robot tips over the opposite edge onto the next face, one roll.
pub fn sixbar(p: &SixbarParams) -> SceneSpec {
    let one = one_sixbar(p);
    if p.robots <= 1 {
        return one;
    }
    let mut fleet = SceneSpec {
        name: format!("{} x{}", one.name, p.robots),
        description: format!(
            "{} robots on a grid {ROBOT_SPACING} m apart on one ground (names prefixed rK_), each: {}",
            p.robots, one.description
        ),
        bodies: Vec::new(),
        cables: Vec::new(),
        actuators: Vec::new(),
        deployment: one.deployment.as_ref().map(|d| DeploymentSpec { steps: d.steps, ramps: Vec::new() }),
        ..one.clone()
    };
    let columns = (p.robots as f64).sqrt().ceil() as usize;
    for k in 0..p.robots {
        let prefix = |name: &str| format!("r{k}_{name}");
        let (dx, dy) = ((k % columns) as f64 * ROBOT_SPACING, (k / columns) as f64 * ROBOT_SPACING);
        for b in &one.bodies {
            let ends = b.ends.map(|e| e.map(|[x, y, z]| [round9s(x + dx), round9s(y + dy), z]));
            fleet.bodies.push(BodySpec { name: prefix(&b.name), ends, ..b.clone() });
        }
        for c in &one.cables {
            let route = c.route.iter().map(|r| prefix(r)).collect();
            fleet.cables.push(CableSpec { name: prefix(&c.name), route, ..c.clone() });
        }
        for a in &one.actuators {
            fleet.actuators.push(ActuatorSpec {
                name: prefix(&a.name),
                cable: prefix(&a.cable),
                ..a.clone()
            });
        }
        if let (Some(d), Some(fd)) = (&one.deployment, &mut fleet.deployment) {
            for r in &d.ramps {
                fd.ramps.push(RampSpec { actuator: prefix(&r.actuator), ..r.clone() });
            }
        }
    }
    fleet
}

/// One robot of `sixbar`.
fn one_sixbar(p: &SixbarParams) -> SceneSpec {
    use nalgebra::{Rotation3, Vector3};
    let (l, s) = (p.strut_length, p.strut_length / 4.0);
    // struts by family (the axis they run along) and sign of their offset
    let mut struts: Vec<(String, Vector3<f64>, Vector3<f64>)> = Vec::new();
    for (family, axis) in [("x", 0usize), ("y", 1), ("z", 2)] {
        for (i, sign) in [1.0, -1.0].into_iter().enumerate() {
            // the offset axis follows the running one cyclically backwards: x pairs sit at +-z, y
            // pairs at +-x, z pairs at +-y
            let offset_axis = (axis + 2) % 3;
            let mut a = Vector3::zeros();
            let mut b = Vector3::zeros();
            a[axis] = -l / 2.0;
            b[axis] = l / 2.0;
            a[offset_axis] = sign * s;
            b[offset_axis] = sign * s;
            struts.push((format!("{family}{i}"), a, b));
        }
    }
    let down =
        Rotation3::rotation_between(&Vector3::new(1.0, 1.0, 1.0), &-Vector3::z()).expect("not opposite");
    for (_, a, b) in &mut struts {
        *a = down * *a;
        *b = down * *b;
    }
    let lowest = struts.iter().flat_map(|(_, a, b)| [a.z, b.z]).fold(f64::INFINITY, f64::min);
    let lift = Vector3::new(0.0, 0.0, p.contact_radius - lowest);
    let ends: Vec<(String, Vector3<f64>)> = struts
        .iter()
        .flat_map(|(name, a, b)| [(format!("{name}.a"), a + lift), (format!("{name}.b"), b + lift)])
        .collect();
    let bodies = struts
        .iter()
        .map(|(name, a, b)| {
            let (a, b) = (a + lift, b + lift);
            BodySpec {
                mass: Some(p.bar_mass),
                ends: Some([round9(a), round9(b)]),
                contact_radius: Some(p.contact_radius),
                ..BodySpec::new(name, BodyKindSpec::Bar)
            }
        })
        .collect();
    let cable_length = 6f64.sqrt() * l / 4.0;
    let rest_length = round9s(cable_length / (1.0 + p.prestress / p.ea));
    let mut cables = Vec::new();
    let mut bottom_edge = None;
    for i in 0..ends.len() {
        for j in i + 1..ends.len() {
            let (ni, xi) = &ends[i];
            let (nj, xj) = &ends[j];
            if ni[..1] == nj[..1] || ((xi - xj).norm() - cable_length).abs() > 1e-9 * l {
                continue;
            }
            let name = format!("c{:02}", cables.len());
            if bottom_edge.is_none() && xi.z.max(xj.z) < p.contact_radius + 1e-9 * l {
                bottom_edge = Some(name.clone());
            }
            cables.push(CableSpec {
                name,
                route: vec![ni.clone(), nj.clone()],
                ea: p.ea,
                damping: None,
                damping_ratio: Some(p.damping_ratio),
                rest_length: Some(rest_length),
                prestress: None,
                force_density: None,
                tension_only: true,
                pulley_friction: None,
                winch_end: None,
            });
        }
    }
    let winch_cable = bottom_edge.expect("the bottom face is a cable triangle");
    let winch = |name: String, cable: &str| ActuatorSpec {
        name,
        cable: cable.to_string(),
        min_rest_length: round9s(0.2 * cable_length),
        max_rest_length: round9s(1.2 * cable_length),
        max_rate: round9s(cable_length),
        command_delay: None,
        command_delay_s: None,
        winch: None,
    };
    if p.all_winches {
        let actuators = cables.iter().map(|c| winch(format!("w_{}", c.name), &c.name)).collect();
        return SceneSpec {
            name: "sixbar_rover".into(),
            description: format!(
                "Six-bar tensegrity robot standing on a face of three strut ends on a level ground \
                 (mu {}): struts {} m, {} kg, capsules of radius {} m; 24 cables of EA {} N at {} N, \
                 each on a winch (w_ and its name) for a controller to roll the robot where it wants",
                p.mu, l, p.bar_mass, p.contact_radius, p.ea, p.prestress
            ),
            gravity: [0.0, 0.0, -9.81],
            physics_dt: Some(0.001),
            bodies,
            cables,
            actuators,
            grounds: vec![sixbar_floor(p)],
            ..Default::default()
        };
    }
    SceneSpec {
        name: "sixbar".into(),
        description: format!(
            "Six-bar tensegrity robot standing on a face of three strut ends on a level ground (mu \
             {}): struts {} m, {} kg, capsules of radius {} m; 24 cables of EA {} N at {} N; \
             roll_winch hauls the bottom edge {} in to {} of its length over {} s and the robot \
             rolls onto the next face",
            p.mu,
            l,
            p.bar_mass,
            p.contact_radius,
            p.ea,
            p.prestress,
            winch_cable,
            p.roll_fraction,
            p.roll_duration
        ),
        gravity: [0.0, 0.0, -9.81],
        physics_dt: Some(0.001),
        bodies,
        cables,
        actuators: vec![winch("roll_winch".into(), &winch_cable)],
        deployment: Some(DeploymentSpec {
            steps: 100,
            ramps: vec![RampSpec {
                actuator: "roll_winch".into(),
                start: 0.2,
                duration: p.roll_duration,
                rest_length: round9s(p.roll_fraction * cable_length),
            }],
        }),
        grounds: vec![sixbar_floor(p)],
        ..Default::default()
    }
}

/// The six-bar robots' tangential contact stiffness, N/m: stick-slip friction
/// (`crate::model::StickFriction`), of the order of the floor's normal stiffness, so that a foot at the
/// friction limit gives `mu F_n / k_t`, a few tenths of a millimetre, before it slips. The
/// robots' feet stick without creeping, and the implicit step keeps its factors through most
/// steps (docs/benchmarks.md).
pub const SIXBAR_STICK_STIFFNESS: f64 = 2e4;

/// The floor under the six-bar robots: `mu`, stick-slip friction.
fn sixbar_floor(p: &SixbarParams) -> GroundSpec {
    GroundSpec {
        name: Some("floor".into()),
        mu: Some(p.mu),
        stick_stiffness: Some(SIXBAR_STICK_STIFFNESS),
        ..Default::default()
    }
}

/// `x` rounded to 9 decimals (generated files stay readable and parse back to the same numbers).
fn round9s(x: f64) -> f64 {
    (x * 1e9).round() / 1e9
}

fn round9(v: nalgebra::Vector3<f64>) -> [f64; 3] {
    [round9s(v.x), round9s(v.y), round9s(v.z)]
}

/// A generator chosen by kind with the options `tensegrity generate KIND` takes (the command
/// line and the Python library both build this, so they write the same scene).
#[derive(Debug, Clone, PartialEq)]
pub enum Generator {
    /// `prism`: a regular `n`-strut prism (`n >= 3`) on pinned supports; `cluster` makes its top
    /// ring one actuated cable (shortened 0.1 over the deployment); `prestress`, N, the side
    /// strings' prestress; `nodal_strut_ea`, N, the nodal form (struts as elastic members) with
    /// `consistent_mass`.
    Prism {
        /// Struts.
        n: usize,
        /// Cluster the top ring.
        cluster: bool,
        /// Side-string prestress, N.
        prestress: f64,
        /// The nodal form's strut EA, N.
        nodal_strut_ea: Option<f64>,
        /// Consistent instead of lumped member mass.
        consistent_mass: bool,
    },
    /// `tower`: `stages` (>= 1) stacked `n`-strut prisms (`n >= 3`) with clustered side cables.
    Tower {
        /// Struts per stage.
        n: usize,
        /// Stages.
        stages: usize,
    },
    /// `tbar`: the planar clustered T-bar (`hinged_hub`: Skelton's pin-jointed form).
    Tbar {
        /// Mast and cross bar ball-jointed at the hub.
        hinged_hub: bool,
        /// The nodal form's half-bar EA, N.
        nodal_strut_ea: Option<f64>,
        /// Consistent instead of lumped member mass.
        consistent_mass: bool,
    },
    /// `atwood`: the elastic Atwood machine with masses `m1`, `m2`, kg.
    Atwood {
        /// First mass, kg.
        m1: f64,
        /// Second mass, kg.
        m2: f64,
    },
    /// `sixbar`: the six-bar robot on a ground of friction `mu`; `all_winches`: a winch on every
    /// cable and no schedule; `robots` (1 to 1000) on a grid 3 m apart.
    Sixbar {
        /// Ground friction coefficient.
        mu: f64,
        /// A winch on every cable.
        all_winches: bool,
        /// Robots.
        robots: usize,
    },
}

/// The generators' kinds, as `Generator::toml` and the command line name them.
pub const GENERATOR_KINDS: [&str; 5] = ["prism", "tower", "tbar", "atwood", "sixbar"];

impl Generator {
    /// The scene spec, or why these options make none.
    pub fn spec(&self) -> Result<SceneSpec, String> {
        let mass_matrix = |consistent: bool| match consistent {
            true => MassMatrixSpec::Consistent,
            false => MassMatrixSpec::Lumped,
        };
        Ok(match *self {
            Generator::Prism { n, cluster, prestress, nodal_strut_ea, consistent_mass } => {
                if n < 3 {
                    return Err("a prism needs n >= 3".into());
                }
                prism(&PrismParams {
                    n,
                    cluster_top_ring: cluster,
                    side_prestress: prestress,
                    deploy_shortening: if cluster { 0.1 } else { 0.0 },
                    nodal_strut_ea,
                    nodal_mass_matrix: mass_matrix(consistent_mass),
                    ..Default::default()
                })
            }
            Generator::Tower { n, stages } => {
                if n < 3 || stages < 1 {
                    return Err("a tower needs n >= 3 and stages >= 1".into());
                }
                tower(&TowerParams { n, stages, ..Default::default() })
            }
            Generator::Tbar { hinged_hub, nodal_strut_ea, consistent_mass } => tbar(&TbarParams {
                hinged_hub,
                nodal_strut_ea,
                nodal_mass_matrix: mass_matrix(consistent_mass),
                ..Default::default()
            }),
            Generator::Atwood { m1, m2 } => atwood(&AtwoodParams { m1, m2, ..Default::default() }),
            Generator::Sixbar { mu, all_winches, robots } => {
                if !(1..=1000).contains(&robots) {
                    return Err(format!("robots must be in [1, 1000], got {robots}"));
                }
                sixbar(&SixbarParams { mu, all_winches, robots, ..Default::default() })
            }
        })
    }

    /// The scene as the TOML `tensegrity generate` writes (a comment line, then
    /// `scene::to_toml`), checked as `check` would check it: options that are scene fields out of
    /// range are refused here.
    pub fn toml(&self) -> Result<String, String> {
        let spec = self.spec()?;
        let label = format!("<generated {}>", spec.name);
        super::build_model(&spec, &label, None).map_err(|e| format!("cannot generate: {e}"))?;
        Ok(format!("# generated by `tensegrity generate`\n{}", super::to_toml(&spec)))
    }
}
