//! Invariant: the Rust wire structs and the ROS 2 interface files agree field by field — same
//! names, same types, same order (CDR serializes in field order, so any difference corrupts the
//! wire). The `.msg` files in `msg/msg/` are parsed here; the Rust side is traced with
//! serde-reflection. The standard types used (std_msgs/Header, builtin_interfaces/Time) are
//! checked against their published definitions.

mod common;
use common::bundled;

use std::path::PathBuf;

use serde_reflection::{ContainerFormat, Format, Tracer, TracerConfig};
use tensegrity::io::msg::{ActuatorCommand, CableStates, Structure};

/// (type, name) pairs of a `.msg` text, comments and blank lines skipped.
fn parse_msg(text: &str) -> Vec<(String, String)> {
    text.lines()
        .map(|l| l.split('#').next().unwrap().trim())
        .filter(|l| !l.is_empty())
        .map(|l| {
            let mut it = l.split_whitespace();
            let (ty, name) = (it.next().unwrap(), it.next().expect("a field name"));
            assert!(it.next().is_none(), "constants and defaults are not used: '{l}'");
            (ty.to_string(), name.to_string())
        })
        .collect()
}

fn ros_to_format(ty: &str) -> Format {
    if let Some(inner) = ty.strip_suffix("[]") {
        return Format::Seq(Box::new(ros_to_format(inner)));
    }
    match ty {
        "float64" => Format::F64,
        "string" => Format::Str,
        "bool" => Format::Bool,
        "uint32" => Format::U32,
        "uint64" => Format::U64,
        "int32" => Format::I32,
        "std_msgs/Header" => Format::TypeName("Header".into()),
        "geometry_msgs/Point" => Format::TypeName("Point".into()),
        "geometry_msgs/Vector3" => Format::TypeName("Vector3".into()),
        "builtin_interfaces/Time" => Format::TypeName("Time".into()),
        other => panic!("add a mapping for ROS type '{other}'"),
    }
}

fn fields_of(registry: &serde_reflection::Registry, name: &str) -> Vec<(String, Format)> {
    match registry.get(name) {
        Some(ContainerFormat::Struct(fields)) => {
            fields.iter().map(|f| (f.name.clone(), f.value.clone())).collect()
        }
        other => panic!("{name} is not a struct: {other:?}"),
    }
}

#[test]
fn rust_structs_match_the_msg_files_field_by_field() {
    let mut tracer = Tracer::new(TracerConfig::default());
    tracer.trace_simple_type::<CableStates>().unwrap();
    tracer.trace_simple_type::<ActuatorCommand>().unwrap();
    tracer.trace_simple_type::<Structure>().unwrap();
    tracer.trace_simple_type::<tensegrity::io::msg::AppliedCommands>().unwrap();
    tracer.trace_simple_type::<tensegrity::io::msg::ContactStates>().unwrap();
    tracer.trace_simple_type::<tensegrity::io::msg::TensionCommand>().unwrap();
    tracer.trace_simple_type::<tensegrity::io::msg::ImuStates>().unwrap();
    tracer.trace_simple_type::<tensegrity::io::msg::SensorReadings>().unwrap();
    let registry = tracer.registry().unwrap();
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("msg/msg");
    let mut checked = 0;
    for name in [
        "CableStates",
        "ActuatorCommand",
        "Structure",
        "AppliedCommands",
        "ContactStates",
        "TensionCommand",
        "ImuStates",
        "SensorReadings",
    ] {
        let text = std::fs::read_to_string(dir.join(format!("{name}.msg"))).unwrap();
        let expected: Vec<(String, Format)> =
            parse_msg(&text).into_iter().map(|(ty, n)| (n, ros_to_format(&ty))).collect();
        assert_eq!(fields_of(&registry, name), expected, "{name}.msg and the Rust struct differ");
        checked += 1;
    }
    // every .msg file of the package is covered, and CMakeLists.txt lists them all
    let files: Vec<String> =
        std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    assert_eq!(files.len(), checked, "{files:?}");
    let cmake = std::fs::read_to_string(dir.parent().unwrap().join("CMakeLists.txt")).unwrap();
    for f in &files {
        assert!(cmake.contains(&format!("\"msg/{f}\"")), "CMakeLists.txt does not list {f}");
    }
    // standard types as published by ROS 2
    assert_eq!(
        fields_of(&registry, "Header"),
        vec![("stamp".into(), Format::TypeName("Time".into())), ("frame_id".into(), Format::Str)]
    );
    assert_eq!(
        fields_of(&registry, "Time"),
        vec![("sec".into(), Format::I32), ("nanosec".into(), Format::U32)]
    );
}

#[test]
fn wire_conversions_carry_the_state_and_refuse_bad_commands_whole() {
    use tensegrity::evaluate::{evaluate, Tangents, Workspace};
    use tensegrity::io::commands::MessageError;
    use tensegrity::io::msg::Time;
    let model = bundled("tower.toml");
    let state = tensegrity::State::initial(&model);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    let reference = tensegrity::report::all_pulley_coordinates(&model, &state, &ws);
    let m = CableStates::from_state(&model, &state, &ws, &reference, "world");
    assert!(m.is_finite());
    assert_eq!(m.name, model.cable_names);
    let segments: u32 = m.segment_count.iter().sum();
    assert_eq!(m.segment_length.len(), segments as usize);
    assert_eq!(m.pulley_slip.len(), segments as usize - m.name.len());
    for per_pulley in [m.pulley_slip_speed.len(), m.pulley_tension_ratio.len(), m.pulley_sticks.len()] {
        assert_eq!(per_pulley, m.pulley_slip.len());
    }
    let s = Structure::from_model(&model, "world");
    assert_eq!(s.cable_route_length.iter().sum::<u32>() as usize, s.route_points.len());

    let t = Time::from_seconds(12.345678901);
    assert_eq!((t.sec, t.nanosec), (12, 345_678_901));

    let ok = ActuatorCommand {
        name: vec!["side0_winch".into(), "side2_winch".into()],
        rest_length: vec![3.8, 3.85],
        ..Default::default()
    };
    assert_eq!(ok.commands(&model).unwrap().len(), 2);
    let nan = ActuatorCommand { rest_length: vec![3.8, f64::NAN], ..ok.clone() };
    assert!(matches!(nan.commands(&model), Err(MessageError::Command(_))));
    let short = ActuatorCommand { rate: vec![0.1], ..ok.clone() };
    assert!(matches!(
        short.commands(&model),
        Err(MessageError::WrongLength { field: "rate", got: 1, names: 2 })
    ));
    let unknown = ActuatorCommand { name: vec!["side0_winch".into(), "nope".into()], ..ok };
    assert!(unknown.commands(&model).is_err());
}

#[test]
fn marker_layout_matches_visualization_msgs() {
    // visualization_msgs/msg/Marker as published for Humble, Jazzy and Rolling (ros2/common_interfaces)
    let official = "std_msgs/Header header; string ns; int32 id; int32 type; int32 action; geometry_msgs/Pose pose; \
        geometry_msgs/Vector3 scale; std_msgs/ColorRGBA color; builtin_interfaces/Duration lifetime; bool frame_locked; \
        geometry_msgs/Point[] points; std_msgs/ColorRGBA[] colors; string texture_resource; sensor_msgs/CompressedImage texture; \
        UVCoordinate[] uv_coordinates; string text; string mesh_resource; MeshFile mesh_file; bool mesh_use_embedded_materials";
    let expected: Vec<(String, Format)> = official
        .split(';')
        .map(|f| {
            let mut it = f.split_whitespace();
            let (ty, name) = (it.next().unwrap(), it.next().unwrap());
            let base = ty.trim_end_matches("[]");
            let leaf = match base {
                "int32" => Format::I32,
                "string" => Format::Str,
                "bool" => Format::Bool,
                "std_msgs/Header" => Format::TypeName("Header".into()),
                "geometry_msgs/Pose" => Format::TypeName("Pose".into()),
                "geometry_msgs/Vector3" => Format::TypeName("Vector3".into()),
                "geometry_msgs/Point" => Format::TypeName("Point".into()),
                "std_msgs/ColorRGBA" => Format::TypeName("ColorRgba".into()),
                "builtin_interfaces/Duration" => Format::TypeName("Duration".into()),
                "sensor_msgs/CompressedImage" => Format::TypeName("CompressedImage".into()),
                "UVCoordinate" => Format::TypeName("UvCoordinate".into()),
                "MeshFile" => Format::TypeName("MeshFile".into()),
                other => panic!("{other}"),
            };
            let format = if ty.ends_with("[]") { Format::Seq(Box::new(leaf)) } else { leaf };
            (name.to_string(), format)
        })
        .collect();
    let mut tracer = Tracer::new(TracerConfig::default());
    tracer.trace_simple_type::<tensegrity::io::msg::MarkerArray>().unwrap();
    let registry = tracer.registry().unwrap();
    assert_eq!(fields_of(&registry, "Marker"), expected);
    assert_eq!(
        fields_of(&registry, "ColorRgba"),
        ["r", "g", "b", "a"].iter().map(|n| (n.to_string(), Format::F32)).collect::<Vec<_>>()
    );
}

/// Checks the ROS definition of `ros_type` (as `io::schemas` gives it to bags) against the traced
/// Rust struct `rust_name`, field by field and through every nested message type.
fn check_definition(
    registry: &serde_reflection::Registry,
    ros_type: &str,
    rust_name: &str,
    checked: &mut Vec<String>,
) {
    use tensegrity::io::schemas;
    let text = schemas::definition(ros_type).unwrap_or_else(|| panic!("no definition of {ros_type}"));
    let pkg = ros_type.split('/').next().unwrap();
    let rust = fields_of(registry, rust_name);
    let ros = schemas::fields(text);
    assert_eq!(ros.len(), rust.len(), "{ros_type} vs {rust_name}: {ros:?} / {rust:?}");
    for ((ty, name), (rust_field, format)) in ros.iter().zip(&rust) {
        assert_eq!(name, rust_field, "{ros_type}: field order");
        let (base, format) = match (ty.strip_suffix("[]"), format) {
            (Some(base), Format::Seq(inner)) => (base, inner.as_ref()),
            (Some(_), other) => panic!("{ros_type}.{name}: an array in ROS, {other:?} in Rust"),
            (None, f) => (*ty, f),
        };
        let primitive = match base {
            "float64" => Some(Format::F64),
            "float32" => Some(Format::F32),
            "string" => Some(Format::Str),
            "bool" => Some(Format::Bool),
            "int32" => Some(Format::I32),
            "uint32" => Some(Format::U32),
            "uint64" => Some(Format::U64),
            "uint8" | "byte" => Some(Format::U8),
            _ => None,
        };
        match (primitive, format) {
            (Some(p), f) => assert_eq!(&p, f, "{ros_type}.{name}"),
            (None, Format::TypeName(inner)) => {
                let nested = if base.contains('/') { base.to_string() } else { format!("{pkg}/{base}") };
                check_definition(registry, &nested, inner, checked);
            }
            (None, other) => panic!("{ros_type}.{name}: message {base} in ROS, {other:?} in Rust"),
        }
    }
    checked.push(ros_type.to_string());
}

#[test]
fn every_type_a_bag_records_has_a_definition_equal_to_its_rust_struct() {
    use tensegrity::io::{msg, schemas, topics::Topic};
    let mut tracer = Tracer::new(TracerConfig::default());
    tracer.trace_simple_type::<msg::Clock>().unwrap();
    tracer.trace_simple_type::<msg::TfMessage>().unwrap();
    tracer.trace_simple_type::<msg::PoseArray>().unwrap();
    tracer.trace_simple_type::<CableStates>().unwrap();
    tracer.trace_simple_type::<msg::JointState>().unwrap();
    tracer.trace_simple_type::<Structure>().unwrap();
    tracer.trace_simple_type::<msg::DiagnosticArray>().unwrap();
    tracer.trace_simple_type::<msg::MarkerArray>().unwrap();
    tracer.trace_simple_type::<msg::AppliedCommands>().unwrap();
    tracer.trace_simple_type::<ActuatorCommand>().unwrap();
    tracer.trace_simple_type::<msg::ContactStates>().unwrap();
    tracer.trace_simple_type::<msg::TensionCommand>().unwrap();
    tracer.trace_simple_type::<msg::ImuStates>().unwrap();
    tracer.trace_simple_type::<msg::SensorReadings>().unwrap();
    let registry = tracer.registry().unwrap();
    let rust_of = [
        ("rosgraph_msgs/msg/Clock", "Clock"),
        ("tf2_msgs/msg/TFMessage", "TfMessage"),
        ("geometry_msgs/msg/PoseArray", "PoseArray"),
        ("tensegrity_msgs/msg/CableStates", "CableStates"),
        ("sensor_msgs/msg/JointState", "JointState"),
        ("tensegrity_msgs/msg/Structure", "Structure"),
        ("diagnostic_msgs/msg/DiagnosticArray", "DiagnosticArray"),
        ("visualization_msgs/msg/MarkerArray", "MarkerArray"),
        ("tensegrity_msgs/msg/AppliedCommands", "AppliedCommands"),
        ("tensegrity_msgs/msg/ActuatorCommand", "ActuatorCommand"),
        ("tensegrity_msgs/msg/ContactStates", "ContactStates"),
        ("tensegrity_msgs/msg/TensionCommand", "TensionCommand"),
        ("tensegrity_msgs/msg/ImuStates", "ImuStates"),
        ("tensegrity_msgs/msg/SensorReadings", "SensorReadings"),
    ];
    // every topic a bag records is covered
    for topic in Topic::ALL {
        if let Some((ty, _)) = tensegrity::io::topics::topic_type(topic) {
            assert!(rust_of.iter().any(|(t, _)| *t == ty), "{ty} of {topic:?} is not checked here");
        }
    }
    let mut checked = Vec::new();
    for (ros, rust) in rust_of {
        let short = ros.replace("/msg/", "/");
        check_definition(&registry, &short, rust, &mut checked);
        // the full text a bag stores names each dependency once, after its separator line
        let full = schemas::full_definition(ros).unwrap();
        for dep in schemas::dependencies(&short) {
            assert_eq!(full.matches(&format!("\nMSG: {dep}\n")).count(), 1, "{ros}: {dep}");
        }
    }
    // and every definition the module has was reached
    for known in schemas::known_types() {
        assert!(checked.iter().any(|c| c == known), "{known} is never checked");
    }
}

/// The Python kit's message classes are generated from the same definitions (`python_module`):
/// the shipped file is that text. `TENSEGRITY_BLESS=1` rewrites it after a change to `msg/`.
#[test]
fn the_python_kits_message_classes_are_generated_from_msg() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("python/tensegrity/testing/msgs.py");
    let generated = tensegrity::io::schemas::python_module();
    if std::env::var_os("TENSEGRITY_BLESS").is_some() {
        std::fs::write(&path, &generated).unwrap();
    }
    let shipped = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        shipped == generated,
        "{} is not what msg/ generates: run TENSEGRITY_BLESS=1 cargo test --test msg_sync",
        path.display()
    );
    // every message definition has its class, with the DDS type name ROS 2 uses
    for ty in tensegrity::io::schemas::known_types() {
        let (pkg, class) = ty.split_once('/').unwrap();
        assert!(
            generated.contains(&format!("class {class}(IdlStruct, typename=\"{pkg}::msg::dds_::{class}_\")"))
        );
    }
}
