//! ROS 2 message definitions for bags: takes a message type name (`geometry_msgs/msg/PoseArray`),
//! gives its full `ros2msg` definition, the text rosbag2 stores as an MCAP schema: the type's own
//! fields, then each type it uses (depth first, each once) after a line of 80 `=` and
//! `MSG: pkg/Type`. Our `tensegrity_msgs` definitions are the `.msg` files of `msg/msg/`; the
//! standard ones are their published field lists (ROS 2 Humble to Rolling; comments left out).
//! `tests/msg_sync.rs` checks every definition here against the Rust wire structs field by field.

/// Every definition, by `pkg/Type`.
const DEFINITIONS: &[(&str, &str)] = &[
    ("tensegrity_msgs/ActuatorCommand", include_str!("../../msg/msg/ActuatorCommand.msg")),
    ("tensegrity_msgs/AppliedCommands", include_str!("../../msg/msg/AppliedCommands.msg")),
    ("tensegrity_msgs/CableStates", include_str!("../../msg/msg/CableStates.msg")),
    ("tensegrity_msgs/ContactStates", include_str!("../../msg/msg/ContactStates.msg")),
    ("tensegrity_msgs/ImuStates", include_str!("../../msg/msg/ImuStates.msg")),
    ("tensegrity_msgs/SensorReadings", include_str!("../../msg/msg/SensorReadings.msg")),
    ("tensegrity_msgs/Structure", include_str!("../../msg/msg/Structure.msg")),
    ("tensegrity_msgs/TensionCommand", include_str!("../../msg/msg/TensionCommand.msg")),
    ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
    ("builtin_interfaces/Duration", "int32 sec\nuint32 nanosec\n"),
    ("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n"),
    ("std_msgs/ColorRGBA", "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n"),
    ("rosgraph_msgs/Clock", "builtin_interfaces/Time clock\n"),
    ("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n"),
    ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n"),
    ("geometry_msgs/Quaternion", "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"),
    ("geometry_msgs/Pose", "Point position\nQuaternion orientation\n"),
    ("geometry_msgs/PoseArray", "std_msgs/Header header\nPose[] poses\n"),
    ("geometry_msgs/Transform", "Vector3 translation\nQuaternion rotation\n"),
    ("geometry_msgs/TransformStamped", "std_msgs/Header header\nstring child_frame_id\nTransform transform\n"),
    ("tf2_msgs/TFMessage", "geometry_msgs/TransformStamped[] transforms\n"),
    (
        "sensor_msgs/JointState",
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
    ),
    ("sensor_msgs/CompressedImage", "std_msgs/Header header\nstring format\nuint8[] data\n"),
    ("diagnostic_msgs/KeyValue", "string key\nstring value\n"),
    (
        "diagnostic_msgs/DiagnosticStatus",
        "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\nstring message\n\
         string hardware_id\nKeyValue[] values\n",
    ),
    ("diagnostic_msgs/DiagnosticArray", "std_msgs/Header header\nDiagnosticStatus[] status\n"),
    ("visualization_msgs/UVCoordinate", "float32 u\nfloat32 v\n"),
    ("visualization_msgs/MeshFile", "string filename\nuint8[] data\n"),
    (
        "visualization_msgs/Marker",
        "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\nint32 LINE_LIST=5\n\
         int32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\nint32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\n\
         int32 TRIANGLE_LIST=11\nint32 ARROW_STRIP=12\nint32 ADD=0\nint32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n\
         std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\ngeometry_msgs/Pose pose\n\
         geometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\nbuiltin_interfaces/Duration lifetime\n\
         bool frame_locked\ngeometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring texture_resource\n\
         sensor_msgs/CompressedImage texture\nUVCoordinate[] uv_coordinates\nstring text\nstring mesh_resource\n\
         MeshFile mesh_file\nbool mesh_use_embedded_materials\n",
    ),
    ("visualization_msgs/MarkerArray", "Marker[] markers\n"),
];

/// Field types that are not messages.
const PRIMITIVES: &[&str] = &[
    "bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
    "float32", "float64", "string", "wstring",
];

/// `pkg/Type` of a type name written `pkg/msg/Type` or `pkg/Type`.
fn short_name(type_name: &str) -> String {
    match type_name.split('/').collect::<Vec<_>>().as_slice() {
        [pkg, "msg", ty] => format!("{pkg}/{ty}"),
        _ => type_name.to_string(),
    }
}

/// The own definition text of `pkg/Type` (or `pkg/msg/Type`), without its dependencies.
pub fn definition(type_name: &str) -> Option<&'static str> {
    let name = short_name(type_name);
    DEFINITIONS.iter().find(|(n, _)| *n == name).map(|(_, t)| *t)
}

/// Every `pkg/Type` this module defines.
pub fn known_types() -> impl Iterator<Item = &'static str> {
    DEFINITIONS.iter().map(|(n, _)| *n)
}

/// The fields of a definition: (type as written, name), comments, constants and blank lines
/// skipped; a default value after the name is dropped.
pub fn fields(text: &str) -> Vec<(&str, &str)> {
    text.lines()
        .map(|l| l.split('#').next().unwrap_or("").trim())
        .filter(|l| !l.is_empty() && !l.contains('='))
        .filter_map(|l| {
            let mut it = l.split_whitespace();
            Some((it.next()?, it.next()?))
        })
        .collect()
}

/// The message types `pkg/Type` uses directly, resolved (`Pose` in `geometry_msgs` is
/// `geometry_msgs/Pose`), in field order, each once.
pub fn dependencies(pkg_type: &str) -> Vec<String> {
    let pkg = pkg_type.split('/').next().unwrap_or("");
    let mut out: Vec<String> = Vec::new();
    for (ty, _) in fields(definition(pkg_type).unwrap_or("")) {
        let base = ty.split('[').next().unwrap_or(ty).split("<=").next().unwrap_or(ty);
        if PRIMITIVES.contains(&base) {
            continue;
        }
        let full = if base.contains('/') { base.to_string() } else { format!("{pkg}/{base}") };
        if !out.contains(&full) {
            out.push(full);
        }
    }
    out
}

/// The full `ros2msg` definition of `type_name` (`pkg/msg/Type`) as rosbag2 stores it: its own
/// text, then every type it uses, directly or not (depth first, each once), each after a line of
/// 80 `=` and `MSG: pkg/Type`. `None` for a type this module does not define (or that uses one).
pub fn full_definition(type_name: &str) -> Option<String> {
    let name = short_name(type_name);
    let mut text = definition(&name)?.to_string();
    let mut seen = vec![name.clone()];
    let mut stack: Vec<String> = dependencies(&name).into_iter().rev().collect();
    while let Some(dep) = stack.pop() {
        if seen.contains(&dep) {
            continue;
        }
        let own = definition(&dep)?;
        if !text.ends_with('\n') {
            text.push('\n');
        }
        text += &format!("{}\nMSG: {dep}\n{own}", "=".repeat(80));
        stack.extend(dependencies(&dep).into_iter().rev());
        seen.push(dep);
    }
    Some(text)
}

/// Python type of a primitive field (`cyclonedds.idl.types` names, `bool`, `str`) and its zero.
fn python_primitive(ty: &str) -> Option<(&'static str, &'static str)> {
    Some(match ty {
        "bool" => ("bool", "False"),
        "byte" => ("types.byte", "0"),
        "char" => ("types.char", "0"),
        "int8" => ("types.int8", "0"),
        "uint8" => ("types.uint8", "0"),
        "int16" => ("types.int16", "0"),
        "uint16" => ("types.uint16", "0"),
        "int32" => ("types.int32", "0"),
        "uint32" => ("types.uint32", "0"),
        "int64" => ("types.int64", "0"),
        "uint64" => ("types.uint64", "0"),
        "float32" => ("types.float32", "0.0"),
        "float64" => ("types.float64", "0.0"),
        "string" | "wstring" => ("str", "\"\""),
        _ => return None,
    })
}

/// The Python class name of `pkg/Type`: `Type`.
fn python_class(pkg_type: &str) -> &str {
    pkg_type.rsplit('/').next().unwrap_or(pkg_type)
}

/// Every message type of this module as Eclipse Cyclone DDS Python classes (`IdlStruct`
/// dataclasses with the ROS 2 DDS type names, `pkg::msg::dds_::Type_`), generated from the same
/// definitions as the bags' schemas (our `msg/` files and the standard types), dependencies first;
/// then `TOPICS`, the node's topics (name, class, QoS depth, transient local) from
/// `topics::topic_type` and `topics::INPUT_TOPICS`. The Python test kit ships this text as
/// `python/tensegrity/testing/msgs.py`; `tests/msg_sync.rs` keeps the file equal to it.
pub fn python_module() -> String {
    use crate::io::topics::Topic;
    use crate::io::topics::{topic_type, INPUT_TOPICS};
    let mut out = String::from(
        "\"\"\"ROS 2 message types of the tensegrity node for Eclipse Cyclone DDS (Python).\n\n\
         GENERATED by `tensegrity::io::schemas::python_module` from msg/ and the standard message\n\
         definitions; do not edit. `cargo test --test msg_sync` checks this file and\n\
         `TENSEGRITY_BLESS=1 cargo test --test msg_sync` rewrites it.\n\"\"\"\n\n\
         from dataclasses import dataclass, field\n\n\
         from cyclonedds.idl import IdlStruct\nfrom cyclonedds.idl import types\n",
    );
    // dependencies first, each once
    let mut order: Vec<String> = Vec::new();
    fn visit(ty: &str, order: &mut Vec<String>) {
        if order.iter().any(|t| t == ty) {
            return;
        }
        for dep in dependencies(ty) {
            visit(&dep, order);
        }
        order.push(ty.to_string());
    }
    for ty in known_types() {
        visit(ty, &mut order);
    }
    for ty in &order {
        let (pkg, class) = (ty.split('/').next().unwrap_or(""), python_class(ty));
        out += &format!(
            "\n\n@dataclass\nclass {class}(IdlStruct, typename=\"{pkg}::msg::dds_::{class}_\"):\n    \"\"\"`{pkg}/msg/{class}`.\"\"\"\n\n"
        );
        let text = definition(ty).unwrap_or("");
        for line in text.lines().map(|l| l.split('#').next().unwrap_or("").trim()) {
            // constants: `byte OK=0`
            if let Some((lhs, value)) = line.split_once('=') {
                let name = lhs.split_whitespace().nth(1).unwrap_or("");
                out += &format!("    {name} = {}\n", value.trim());
            }
        }
        for (written, name) in fields(text) {
            let (base, array) = match written.split_once('[') {
                Some((b, rest)) => (b, Some(rest.trim_end_matches(']'))),
                None => (written, None),
            };
            let element = match python_primitive(base) {
                Some((t, zero)) => (t.to_string(), zero.to_string(), true),
                None => (python_class(base).to_string(), format!("{}()", python_class(base)), false),
            };
            let default =
                text.lines().filter_map(|l| l.split('#').next()).map(str::split_whitespace).find_map(
                    |mut w| (w.next() == Some(written) && w.next() == Some(name)).then(|| w.next()).flatten(),
                );
            let line = match array {
                Some("") => format!("{name}: types.sequence[{}] = field(default_factory=list)", element.0),
                Some(n) => format!(
                    "{name}: types.array[{}, {n}] = field(default_factory=lambda: [{}] * {n})",
                    element.0, element.1
                ),
                None if element.2 => {
                    // a float's default is written as a float (`float64 w 1` is 1.0)
                    let value = match default {
                        Some(d) if element.1 == "0.0" && !d.contains('.') => format!("{d}.0"),
                        Some(d) => d.to_string(),
                        None => element.1.clone(),
                    };
                    format!("{name}: {} = {value}", element.0)
                }
                None => format!("{name}: {} = field(default_factory={})", element.0, element.0),
            };
            out += &format!("    {line}\n");
        }
    }
    out += "\n\n# The node's topics: name (`~/` is the node's private namespace) -> (class, QoS depth,\n\
            # transient local), as the node publishes and subscribes them.\nTOPICS = {\n";
    let mut topics: Vec<(String, String, u32, bool)> = Topic::ALL
        .iter()
        .filter_map(|t| {
            topic_type(*t).map(|(ty, q)| (t.name().to_string(), short_name(ty), q.depth, q.transient_local))
        })
        .collect();
    for (name, ty, q) in INPUT_TOPICS {
        topics.push((name.to_string(), short_name(ty), q.depth, q.transient_local));
    }
    for (name, ty, depth, transient) in topics {
        let transient = if transient { "True" } else { "False" };
        out += &format!("    \"{name}\": ({}, {depth}, {transient}),\n", python_class(&ty));
    }
    out += "}\n";
    out
}
