//! Reading bags in tests: with the independent Python `rosbags` package
//! (`tests/interop/read_bag.py`) and with our own reader, as comparable topic counts.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;
use tensegrity::io::msg::AppliedCommands;
use tensegrity::io::record::bag::BagReader;

use super::python;

/// The bag as the Python `rosbags` reader sees it (`tests/interop/read_bag.py`), or `None` (and
/// a SKIPPED note) when no Python with `rosbags` is around and none was named.
pub fn rosbags_read(dir: &Path) -> Option<Value> {
    let python = python::python_with("rosbags")?;
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let out = Command::new(&python)
        .arg(root.join("tests/interop/read_bag.py"))
        .arg(dir)
        .arg(root.join("msg/msg"))
        .output()
        .unwrap();
    assert!(out.status.success(), "read_bag.py failed: {}", String::from_utf8_lossy(&out.stderr));
    Some(serde_json::from_slice(&out.stdout).unwrap())
}

/// Topic -> (type, count) of a `rosbags_read` result.
pub fn rosbags_counts(v: &Value) -> BTreeMap<String, (String, u64)> {
    v["topics"]
        .as_object()
        .unwrap()
        .iter()
        .map(|(k, t)| (k.clone(), (t["type"].as_str().unwrap().to_string(), t["count"].as_u64().unwrap())))
        .collect()
}

/// Topic -> (type, count) as our own reader counts the bag.
pub fn our_counts(dir: &Path) -> BTreeMap<String, (String, u64)> {
    let info = BagReader::open(dir).unwrap().info();
    info.topics.into_iter().map(|(t, n)| (t.name, (t.type_name, n))).collect()
}

pub fn floats(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

/// The bag's `~/applied_commands` messages of the default node, decoded, in order.
pub fn applied_commands(reader: &BagReader) -> Vec<AppliedCommands> {
    reader
        .messages()
        .map(Result::unwrap)
        .filter(|m| m.topic == "/tensegrity_sim/applied_commands")
        .map(|m| tensegrity::io::record::applied_commands(&m).unwrap())
        .collect()
}
