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
    ("tensegrity_msgs/Structure", include_str!("../../msg/msg/Structure.msg")),
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
