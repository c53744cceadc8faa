//! The node's one topic table: takes a `Topic` (what the node publishes) or an input, gives its
//! name (`~/` is the node's private namespace), its ROS message type and the QoS it is offered
//! with. The DDS transport creates its writers and readers from it, the bags declare their
//! channels with it, and the Python kit's `msgs.TOPICS` is generated from it
//! (`io::schemas::python_module`).

/// Every topic the node publishes, for per-topic failure counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Topic {
    /// `/clock`.
    Clock,
    /// `/tf`.
    Tf,
    /// `/tf_static`.
    TfStatic,
    /// `~/body_poses`.
    BodyPoses,
    /// `~/cable_states`.
    CableStates,
    /// `~/actuator_states`.
    ActuatorStates,
    /// `~/structure`.
    Structure,
    /// `/diagnostics`.
    Diagnostics,
    /// `~/markers`.
    Markers,
    /// `~/contacts` (only scenes with grounds publish it: `Topic::published_by`).
    Contacts,
    /// The whole state in one sample (body poses, cables, actuators, time and step index), for
    /// transports that carry it so (shared memory); published with the other state topics.
    State,
    /// `~/ground_truth/body_poses`: the exact poses, where the scene's sensors make
    /// `~/body_poses` report measured ones (only such scenes publish it).
    GroundTruthPoses,
    /// `~/ground_truth/cable_states`: the exact cable states, where sensors make
    /// `~/cable_states` report measured tensions, lengths or rest lengths.
    GroundTruthCables,
    /// `~/imu`: every body's IMU as its sensors report it (only scenes that declare a gyro or
    /// an accelerometer publish it).
    Imu,
    /// `~/ground_truth/imu`: the exact IMU values (with `~/imu`).
    GroundTruthImu,
    /// `~/sensor_readings`: every declared channel's reported values with a lost flag per value
    /// (only scenes that declare sensors publish it).
    SensorReadings,
}

impl Topic {
    /// Every topic, in the order of `NodeStats::publish_failures`.
    pub const ALL: [Topic; 16] = [
        Topic::Clock,
        Topic::Tf,
        Topic::TfStatic,
        Topic::BodyPoses,
        Topic::CableStates,
        Topic::ActuatorStates,
        Topic::Structure,
        Topic::Diagnostics,
        Topic::Markers,
        Topic::Contacts,
        Topic::State,
        Topic::GroundTruthPoses,
        Topic::GroundTruthCables,
        Topic::Imu,
        Topic::GroundTruthImu,
        Topic::SensorReadings,
    ];
    /// The topic's name (`~/` is the node's private namespace).
    pub fn name(self) -> &'static str {
        match self {
            Topic::Clock => "/clock",
            Topic::Tf => "/tf",
            Topic::TfStatic => "/tf_static",
            Topic::BodyPoses => "~/body_poses",
            Topic::CableStates => "~/cable_states",
            Topic::ActuatorStates => "~/actuator_states",
            Topic::Structure => "~/structure",
            Topic::Diagnostics => "/diagnostics",
            Topic::Markers => "~/markers",
            Topic::Contacts => "~/contacts",
            Topic::State => "~/state",
            Topic::GroundTruthPoses => "~/ground_truth/body_poses",
            Topic::GroundTruthCables => "~/ground_truth/cable_states",
            Topic::Imu => "~/imu",
            Topic::GroundTruthImu => "~/ground_truth/imu",
            Topic::SensorReadings => "~/sensor_readings",
        }
    }
    /// The topic's position in `Topic::ALL` (and in `NodeStats::publish_failures`).
    pub fn index(self) -> usize {
        Topic::ALL.iter().position(|t| *t == self).unwrap_or(0)
    }
    /// The topics of one state, in publish order: the whole-state sample first (a shared-memory
    /// sample takes microseconds, so it does not wait for the DDS messages' serialization).
    pub const STATE: [Topic; 11] = [
        Topic::State,
        Topic::BodyPoses,
        Topic::Tf,
        Topic::CableStates,
        Topic::ActuatorStates,
        Topic::Contacts,
        Topic::GroundTruthPoses,
        Topic::GroundTruthCables,
        Topic::Imu,
        Topic::GroundTruthImu,
        Topic::SensorReadings,
    ];

    /// Whether a node of `model` publishes this topic: `~/contacts` only where the scene declares
    /// grounds and contact spheres, `~/ground_truth/...` only where it declares sensors (a scene
    /// without has no such topic, no writer and no bag channel), every other topic always.
    pub fn published_by(self, model: &crate::model::Model) -> bool {
        match self {
            Topic::Contacts => model.contact_pairs() > 0,
            Topic::GroundTruthPoses | Topic::GroundTruthCables | Topic::SensorReadings => {
                !model.sensors.channels.is_empty()
            }
            Topic::Imu | Topic::GroundTruthImu => crate::sensors::has_imu(model),
            _ => true,
        }
    }
}

/// QoS a topic is offered with (what `ros2 bag play` offers again): reliable, keep last `depth`,
/// volatile or transient local.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TopicQos {
    /// History depth.
    pub depth: u32,
    /// Transient local (late joiners get the last samples) instead of volatile.
    pub transient_local: bool,
}

impl TopicQos {
    /// The `offered_qos_profiles` text of rosbag2 (a YAML list of one profile; infinite
    /// durations as rmw writes them). The same text goes into the channel and `metadata.yaml`:
    /// the Python `rosbags` reader yields nothing for a topic whose two texts differ.
    pub fn profiles_yaml(&self) -> String {
        let infinite = "\n    sec: 9223372036\n    nsec: 854775807";
        format!(
            "- history: 1\n  depth: {}\n  reliability: 1\n  durability: {}\n  deadline:{infinite}\n  \
             lifespan:{infinite}\n  liveliness: 1\n  liveliness_lease_duration:{infinite}\n  \
             avoid_ros_namespace_conventions: false",
            self.depth,
            if self.transient_local { 1 } else { 2 }
        )
    }
}

/// Name of the applied-commands topic in the node's private namespace.
pub const APPLIED_COMMANDS: &str = "applied_commands";

/// The ROS type and offered QoS of a topic; `None` for the shared-memory whole-state sample. The
/// one table of them: the DDS transport creates its topics and writers from it, the bags
/// declare their channels with it and the Python kit's `msgs.TOPICS` is generated from it.
pub fn topic_type(topic: Topic) -> Option<(&'static str, TopicQos)> {
    let q = |depth, transient_local| TopicQos { depth, transient_local };
    // volatile writers keep at least 16 samples (io::ros2::MIN_WRITER_DEPTH)
    Some(match topic {
        Topic::Clock => ("rosgraph_msgs/msg/Clock", q(16, false)),
        Topic::Tf => ("tf2_msgs/msg/TFMessage", q(100, false)),
        Topic::TfStatic => ("tf2_msgs/msg/TFMessage", q(1, true)),
        Topic::BodyPoses => ("geometry_msgs/msg/PoseArray", q(16, false)),
        Topic::CableStates => ("tensegrity_msgs/msg/CableStates", q(16, false)),
        Topic::ActuatorStates => ("sensor_msgs/msg/JointState", q(16, false)),
        Topic::Structure => ("tensegrity_msgs/msg/Structure", q(1, true)),
        Topic::Diagnostics => ("diagnostic_msgs/msg/DiagnosticArray", q(16, false)),
        Topic::Markers => ("visualization_msgs/msg/MarkerArray", q(16, false)),
        Topic::Contacts => ("tensegrity_msgs/msg/ContactStates", q(16, false)),
        Topic::State => return None,
        Topic::GroundTruthPoses => ("geometry_msgs/msg/PoseArray", q(16, false)),
        Topic::GroundTruthCables => ("tensegrity_msgs/msg/CableStates", q(16, false)),
        Topic::Imu | Topic::GroundTruthImu => ("tensegrity_msgs/msg/ImuStates", q(16, false)),
        Topic::SensorReadings => ("tensegrity_msgs/msg/SensorReadings", q(16, false)),
    })
}

/// The node's input topics: name (`~/` is the node's private namespace), type and QoS, as the DDS
/// transport subscribes them.
pub const INPUT_TOPICS: [(&str, &str, TopicQos); 3] = [
    (
        "~/actuator_commands",
        "tensegrity_msgs/msg/ActuatorCommand",
        TopicQos { depth: 1, transient_local: false },
    ),
    ("~/joint_commands", "sensor_msgs/msg/JointState", TopicQos { depth: 1, transient_local: false }),
    (
        "~/tension_commands",
        "tensegrity_msgs/msg/TensionCommand",
        TopicQos { depth: 1, transient_local: false },
    ),
];

/// The full name of `topic_short` for a node whose private namespace is `private_namespace`
/// (`NodeParams::private_namespace`, `<ns>/<node>`): `~/x` is `<ns>/<node>/x`, other names are
/// kept.
pub fn topic_name(topic_short: &str, private_namespace: &str) -> String {
    match topic_short.strip_prefix("~/") {
        Some(rest) => format!("{private_namespace}/{rest}"),
        None => topic_short.to_string(),
    }
}

/// The name a bag gives the applied-commands topic of a node whose private namespace is
/// `private_namespace`.
pub fn applied_commands_topic(private_namespace: &str) -> String {
    topic_name(&format!("~/{APPLIED_COMMANDS}"), private_namespace)
}
