//! rosbag2 bags: takes ROS messages (any serde wire type of `io::msg`) with their topic, log time
//! and step, gives a rosbag2 directory (`metadata.yaml` and one MCAP file, profile `ros2`,
//! `ros2msg` schemas from `io::schemas`, `cdr` little-endian messages, each channel carrying its
//! `offered_qos_profiles`), and reads such a directory back (`BagReader`), also when it was cut
//! short.
//!
//! Writing happens on a thread of its own (`BagWriter`): the caller serializes a message into a
//! recycled buffer and queues it, the thread compresses (zstd) and writes. The thread takes the
//! queue in batches, waking `DRAIN_PERIOD` after the latest queued job rather than blocking on the
//! queue, so queueing a message never has to wake it: on a real-time node's thread a wake-up is a
//! system call per message (tens of microseconds per step on our 2-core virtual machine). Chunks close at
//! `BagOptions::chunk_size` bytes or after `BagOptions::flush_period`, whichever comes first, and
//! `metadata.yaml` is rewritten then; a closed chunk is in the file (in the kernel's page cache:
//! a killed process loses nothing written before it, a power cut may). So a run of hours never
//! keeps more than a chunk in memory, and a crash or SIGKILL loses at most the last chunk: the
//! file then has no summary and no end magic, which MCAP readers that scan (`BagReader`, the
//! `mcap` CLI) accept and indexed readers (Python `rosbags`) refuse until `reindex` rewrites it.
//!
//! The run a bag records (scene text, simulator settings, node parameters) is the MCAP metadata
//! record `tensegrity` (`RunInfo`), written first so even a cut bag keeps it.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Receiver, SyncSender, TryRecvError, TrySendError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mcap::sans_io::LinearReaderOptions;

use byteorder::LittleEndian;
use serde::Serialize;

use crate::io::schemas;
use crate::io::topics::TopicQos;

/// The CDR encapsulation header of a little-endian message (`CDR_LE`, options 0).
pub const CDR_LE_HEADER: [u8; 4] = [0, 1, 0, 0];
/// Writes `message` into `out` (cleared first) as a rosbag2 `cdr` message: the encapsulation
/// header `CDR_LE_HEADER`, then the little-endian CDR body.
pub fn encode_cdr<M: Serialize>(out: &mut Vec<u8>, message: &M) -> Result<(), cdr_encoding::Error> {
    out.clear();
    out.extend_from_slice(&CDR_LE_HEADER);
    cdr_encoding::to_writer::<_, LittleEndian, _>(out, message)
}

/// Name of the MCAP metadata record that holds `RunInfo`.
pub const RUN_METADATA: &str = "tensegrity";
/// Version of `metadata.yaml` written (rosbag2 of Jazzy and later; Python `rosbags` reads it).
pub const METADATA_VERSION: u32 = 9;

/// Why a bag could not be written or read. Each names the path.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    /// A file or directory could not be created, written or read.
    #[error("{path}: {reason}")]
    Io {
        /// The path.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The MCAP data is not what a bag of ours holds.
    #[error("{path}: {reason}")]
    Format {
        /// The path.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// A message could not be serialized (or the writer thread has stopped).
    #[error("{0}")]
    Write(String),
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> BagError {
    BagError::Io { path: path.to_path_buf(), reason: e.to_string() }
}

/// One topic of a bag.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicSpec {
    /// Full topic name (`/tensegrity_sim/cable_states`).
    pub name: String,
    /// Message type, `pkg/msg/Type` (one `io::schemas` defines).
    pub type_name: String,
    /// Offered QoS.
    pub qos: TopicQos,
}

/// What was run, as the MCAP metadata record `tensegrity`: string keys and values (scene text,
/// settings; see `io::record` for the keys), so that `replay` can run it again.
pub type RunInfo = BTreeMap<String, String>;

/// How a bag is written.
#[derive(Debug, Clone, PartialEq)]
pub struct BagOptions {
    /// zstd-compressed chunks (default true).
    pub compress: bool,
    /// A chunk closes once it holds this many uncompressed bytes (default 1 MiB).
    pub chunk_size: u64,
    /// A chunk closes after this long at the latest, and `metadata.yaml` is rewritten (default
    /// 1 s): at most this much is lost when the process is killed.
    pub flush_period: Duration,
    /// Jobs the writer thread may have queued (a message, or a snapshot of several, `compose`);
    /// beyond that `write` refuses droppable ones and waits for the others (default 65536).
    pub queue: usize,
    /// Run the writer thread at a lower priority (nice `BACKGROUND_NICE`, Linux), so that on a
    /// machine with few cores it never delays the thread that records (a node stepping in real
    /// time). Off by default: an offline run, whose main thread never waits, would then outrun
    /// its writer on a busy machine and fill the queue (default false).
    pub background: bool,
}

/// The nice value of a `BagOptions::background` writer thread: against a thread at the default
/// nice 0 it gets about a tenth of a shared core (CFS weights 110 against 1024), 2.5 to 5 times
/// what a node recording every step at 1 kHz needs of it (18-40 us of CPU per step for prism3
/// and the 3-stage tower, bench `record_overhead`).
pub const BACKGROUND_NICE: i32 = 10;

impl Default for BagOptions {
    fn default() -> Self {
        Self {
            compress: true,
            chunk_size: 1 << 20,
            flush_period: Duration::from_secs(1),
            queue: 1 << 16,
            background: false,
        }
    }
}

/// A topic's handle in a `BagWriter` (its index in the topic list).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BagTopic(pub usize);

enum Job {
    Message { topic: usize, sequence: u32, log_time: u64, data: Vec<u8> },
    Compose(Box<dyn Compose>),
    Finish,
}

/// Where `Compose::compose` hands each message: `(topic, sequence, log_time, cdr)`.
pub type MessageOut<'a> = dyn FnMut(BagTopic, u32, u64, &[u8]) + 'a;

/// Messages that the writer thread builds and serializes from a caller's snapshot, so that the
/// caller only copies its data (`BagWriter::compose`): a real-time thread hands over a step's
/// state and the writer thread pays for the messages.
pub trait Compose: Send + 'static {
    /// Serializes the snapshot's messages in order, calling `out(topic, sequence, log_time,
    /// cdr)` for each (`cdr` starts with the CDR encapsulation header).
    fn compose(&mut self, out: &mut MessageOut<'_>);
    /// How many of the caller's items (states, messages) the snapshot carries: what
    /// `BagWriter::dropped` counts when a full queue refuses it, and what a queue of
    /// `BagOptions::queue` items holds (default 1).
    fn items(&self) -> u64 {
        1
    }
    /// The snapshot as `Any`, for the caller to take its own type back (`BagWriter::recycled`).
    fn into_any(self: Box<Self>) -> Box<dyn std::any::Any + Send>;
}

/// What a finished bag holds.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BagSummary {
    /// Messages per topic, in topic order.
    pub counts: Vec<u64>,
    /// Earliest and latest log time, ns.
    pub time_range: Option<(u64, u64)>,
    /// Size of the MCAP file, bytes.
    pub file_bytes: u64,
}

/// Writes a rosbag2 directory from any thread: see the module docs.
pub struct BagWriter {
    dir: PathBuf,
    topics: Vec<TopicSpec>,
    jobs: Option<SyncSender<Job>>,
    recycled: Receiver<Vec<u8>>,
    recycled_snapshots: Receiver<Box<dyn Compose>>,
    thread: Option<JoinHandle<Result<BagSummary, BagError>>>,
    dropped: u64,
    /// When the latest job was queued (`QueueClock`), for the writer thread's wake-ups.
    queued: QueueClock,
}

/// When the caller last queued a job, in nanoseconds since the writer was created: one atomic
/// store per job on the caller's side, read by the writer thread to time its wake-ups.
#[derive(Clone)]
struct QueueClock {
    epoch: Instant,
    latest: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl QueueClock {
    fn new() -> Self {
        Self { epoch: Instant::now(), latest: Default::default() }
    }

    fn mark(&self) {
        let now = self.epoch.elapsed().as_nanos() as u64;
        self.latest.store(now, std::sync::atomic::Ordering::Relaxed);
    }

    /// Time since the latest job was queued.
    fn since_latest(&self) -> Duration {
        let latest = Duration::from_nanos(self.latest.load(std::sync::atomic::Ordering::Relaxed));
        self.epoch.elapsed().saturating_sub(latest)
    }
}

/// The MCAP file of a bag directory `dir`: `<dir name>_0.mcap`, as rosbag2 names it.
pub fn mcap_file_name(dir: &Path) -> String {
    let stem = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "bag".into());
    format!("{stem}_0.mcap")
}

impl BagWriter {
    /// Creates the bag directory `dir` (it must not exist, or be empty) with `topics` (each type
    /// defined in `io::schemas`) and `run` as its metadata record, and starts the writer thread.
    pub fn create(
        dir: &Path,
        topics: Vec<TopicSpec>,
        run: &RunInfo,
        options: &BagOptions,
    ) -> Result<Self, BagError> {
        if dir.exists() {
            let empty = std::fs::read_dir(dir).map_err(|e| io_err(dir, e))?.next().is_none();
            if !empty {
                return Err(io_err(dir, "already exists and is not empty (a bag is never overwritten)"));
            }
        }
        std::fs::create_dir_all(dir).map_err(|e| io_err(dir, e))?;
        let mut definitions = Vec::new();
        for t in &topics {
            let text = schemas::full_definition(&t.type_name).ok_or_else(|| BagError::Format {
                path: dir.to_path_buf(),
                reason: format!("topic {}: no definition for type {}", t.name, t.type_name),
            })?;
            definitions.push(text);
        }
        let file_name = mcap_file_name(dir);
        let path = dir.join(&file_name);
        let file = File::create(&path).map_err(|e| io_err(&path, e))?;
        let mut write_options = mcap::WriteOptions::new()
            .profile("ros2")
            .library(format!("tensegrity {}", env!("CARGO_PKG_VERSION")))
            .chunk_size(Some(options.chunk_size))
            .compression(options.compress.then_some(mcap::Compression::Zstd));
        if options.compress {
            // the writer thread is the compressor: no more threads per chunk
            // and level 1: zstd was a third of the writer's time at the default level 3, and
            // level 1 bags were no larger (bench record_overhead, per sim second: tower 572-580
            // kB against 606-610 kB, prism3 287-291 kB against 286-289 kB)
            write_options = write_options.compression_threads(0).compression_level(1);
        }
        let mut writer = write_options.create(BufWriter::new(file)).map_err(|e| io_err(&path, e))?;
        writer
            .write_metadata(&mcap::records::Metadata { name: RUN_METADATA.into(), metadata: run.clone() })
            .map_err(|e| io_err(&path, e))?;
        let mut channels = Vec::new();
        for (t, text) in topics.iter().zip(&definitions) {
            let schema =
                writer.add_schema(&t.type_name, "ros2msg", text.as_bytes()).map_err(|e| io_err(&path, e))?;
            let meta = BTreeMap::from([("offered_qos_profiles".to_string(), t.qos.profiles_yaml())]);
            channels.push(writer.add_channel(schema, &t.name, "cdr", &meta).map_err(|e| io_err(&path, e))?);
        }
        writer.flush().map_err(|e| io_err(&path, e))?;
        let yaml_state = MetadataYaml { dir: dir.to_path_buf(), file_name, topics: topics.clone() };
        yaml_state.write(&vec![0; topics.len()], None)?;
        let (jobs, inbox) = mpsc::sync_channel(options.queue.max(1));
        let (give_back, recycled) = mpsc::sync_channel(options.queue.max(1));
        let (give_back_snapshots, recycled_snapshots) = mpsc::sync_channel(SNAPSHOTS_KEPT);
        let flush_period = options.flush_period;
        let back = GiveBack { buffers: give_back, snapshots: give_back_snapshots };
        let background = options.background;
        let queued = QueueClock::new();
        let clock = queued.clone();
        let thread = std::thread::Builder::new()
            .name("bag writer".into())
            .spawn(move || {
                if background {
                    lower_this_threads_priority(BACKGROUND_NICE);
                }
                write_loop(writer, path, channels, yaml_state, inbox, back, flush_period, clock)
            })
            .map_err(|e| io_err(dir, e))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            topics,
            jobs: Some(jobs),
            recycled,
            recycled_snapshots,
            thread: Some(thread),
            dropped: 0,
            queued,
        })
    }

    /// The bag directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
    /// The topics, in handle order.
    pub fn topics(&self) -> &[TopicSpec] {
        &self.topics
    }
    /// Messages (and a snapshot's items, `Compose::items`) refused because the queue was full
    /// (`droppable` ones only).
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Queues `message` (CDR little-endian behind its encapsulation header) on `topic` with MCAP
    /// `sequence` and `log_time` (ns). A full queue refuses a `droppable` message (counted in
    /// `dropped`) and waits for room for any other. Fails when the message does not serialize
    /// or the writer thread has stopped (its error comes out of `finish`).
    pub fn write<M: Serialize>(
        &mut self,
        topic: BagTopic,
        sequence: u32,
        log_time: u64,
        message: &M,
        droppable: bool,
    ) -> Result<(), BagError> {
        let mut data = self.recycled.try_recv().unwrap_or_default();
        encode_cdr(&mut data, message)
            .map_err(|e| BagError::Write(format!("{}: {e}", self.topics[topic.0].name)))?;
        self.write_serialized(topic, sequence, log_time, data, droppable)
    }

    /// Like `write`, with the message already serialized (`data` starts with the CDR
    /// encapsulation header).
    pub fn write_serialized(
        &mut self,
        topic: BagTopic,
        sequence: u32,
        log_time: u64,
        data: Vec<u8>,
        droppable: bool,
    ) -> Result<(), BagError> {
        self.queue(Job::Message { topic: topic.0, sequence, log_time, data }, droppable)
    }

    /// Queues `job` for the writer thread (see `write` for `droppable`).
    fn queue(&mut self, job: Job, droppable: bool) -> Result<(), BagError> {
        let stopped =
            || BagError::Write("the bag writer has stopped (see the error when the bag closes)".into());
        let jobs = self.jobs.as_ref().ok_or_else(stopped)?;
        let items = match &job {
            Job::Compose(snapshot) => snapshot.items(),
            _ => 1,
        };
        let sent = if droppable {
            match jobs.try_send(job) {
                Ok(()) => Ok(()),
                Err(TrySendError::Full(_)) => {
                    self.dropped += items;
                    return Err(BagError::Write("bag writer queue full: message dropped".into()));
                }
                Err(TrySendError::Disconnected(_)) => Err(()),
            }
        } else {
            jobs.send(job).map_err(|_| ())
        };
        self.queued.mark();
        sent.map_err(|()| stopped())
    }

    /// Queues `snapshot`, whose messages the writer thread builds and writes in queue order
    /// (`Compose`). A droppable snapshot is refused when the queue is full (counted in
    /// `dropped`); any other waits for room.
    pub fn compose(&mut self, snapshot: Box<dyn Compose>, droppable: bool) -> Result<(), BagError> {
        self.queue(Job::Compose(snapshot), droppable)
    }

    /// A snapshot the writer thread has composed and given back, for `compose` to reuse (so a
    /// steady recorder allocates none); `None` when none is free.
    pub fn recycled<T: Compose>(&self) -> Option<Box<T>> {
        self.recycled_snapshots.try_recv().ok().and_then(|s| s.into_any().downcast::<T>().ok())
    }

    /// Closes the last chunk, writes the summary, the footer and the final `metadata.yaml`.
    pub fn finish(mut self) -> Result<BagSummary, BagError> {
        self.close()
    }

    fn close(&mut self) -> Result<BagSummary, BagError> {
        if let Some(jobs) = self.jobs.take() {
            let _ = jobs.send(Job::Finish);
        }
        match self.thread.take() {
            Some(t) => t.join().map_err(|_| BagError::Write("the bag writer thread panicked".into()))?,
            None => Err(BagError::Write("the bag was already closed".into())),
        }
    }
}

impl Drop for BagWriter {
    /// Closes the bag (as `finish`) if it is still open; an error is printed, as nobody is left
    /// to return it to.
    fn drop(&mut self) {
        if self.thread.is_some() {
            if let Err(e) = self.close() {
                eprintln!("bag {}: {e}", self.dir.display());
            }
        }
    }
}

/// How long after the latest queued job the writer thread wakes when it has emptied its queue
/// (at most this long asleep). Timed from the latest job, not from when the queue emptied, the
/// wake-ups lock onto a caller that queues in bursts (a node's step every millisecond): the
/// writer drains just after a burst, in the caller's quiet time, instead of beside its next
/// step on a machine with few cores.
pub const DRAIN_PERIOD: Duration = Duration::from_millis(5);

/// Composed snapshots the writer thread keeps for reuse (a recorder's batches: 64 of them are
/// about 0.3 s of a 1 kHz node's states, slack for a writer held up that long).
const SNAPSHOTS_KEPT: usize = 64;

/// Where the writer thread hands back what the caller may reuse.
struct GiveBack {
    buffers: SyncSender<Vec<u8>>,
    snapshots: SyncSender<Box<dyn Compose>>,
}

/// Sets the calling thread's nice value to `nice` (best effort: where it fails, or off Linux,
/// the thread keeps its priority). On Linux a nice value belongs to one thread, not the process.
fn lower_this_threads_priority(nice: i32) {
    #[cfg(target_os = "linux")]
    #[allow(unsafe_code)]
    // SAFETY: `setpriority` takes plain integers and touches no memory of ours; `who = 0` with
    // `PRIO_PROCESS` is the calling thread on Linux.
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, 0, nice);
    }
    #[cfg(not(target_os = "linux"))]
    let _ = nice;
}

/// The writer thread: writes queued messages (in batches, each `DRAIN_PERIOD` after the latest
/// queued job), closes a chunk every `flush_period`, and finishes.
fn write_loop(
    mut writer: mcap::Writer<BufWriter<File>>,
    path: PathBuf,
    channels: Vec<u16>,
    yaml: MetadataYaml,
    inbox: Receiver<Job>,
    give_back: GiveBack,
    flush_period: Duration,
    queued: QueueClock,
) -> Result<BagSummary, BagError> {
    let mut counts = vec![0u64; channels.len()];
    let mut range: Option<(u64, u64)> = None;
    let mut last_flush = Instant::now();
    let mut unflushed = false;
    let mut failure: Option<BagError> = None;
    loop {
        let mut put = |topic: BagTopic, sequence: u32, log_time: u64, data: &[u8]| {
            if failure.is_some() {
                return;
            }
            let header = mcap::records::MessageHeader {
                channel_id: channels[topic.0],
                sequence,
                log_time,
                publish_time: log_time,
            };
            match writer.write_to_known_channel(&header, data) {
                Ok(()) => {
                    counts[topic.0] += 1;
                    range =
                        Some(range.map_or((log_time, log_time), |(a, b)| (a.min(log_time), b.max(log_time))));
                    unflushed = true;
                }
                Err(e) => failure = Some(io_err(&path, e)),
            }
        };
        match inbox.try_recv() {
            Ok(Job::Message { topic, sequence, log_time, data }) => {
                put(BagTopic(topic), sequence, log_time, &data);
                let _ = give_back.buffers.try_send(data);
            }
            Ok(Job::Compose(mut snapshot)) => {
                snapshot.compose(&mut put);
                let _ = give_back.snapshots.try_send(snapshot);
            }
            Ok(Job::Finish) | Err(TryRecvError::Disconnected) => break,
            Err(TryRecvError::Empty) => {
                // the queue is empty: sleep (the caller never waits on this thread) until
                // `DRAIN_PERIOD` after the latest job, or that long when it is older
                let mut nap = match DRAIN_PERIOD.saturating_sub(queued.since_latest()) {
                    Duration::ZERO => DRAIN_PERIOD,
                    left => left,
                };
                if unflushed {
                    nap = nap.min(flush_period.saturating_sub(last_flush.elapsed()));
                }
                std::thread::sleep(nap);
            }
        }
        if unflushed && failure.is_none() && last_flush.elapsed() >= flush_period {
            if let Err(e) = writer.flush() {
                failure = Some(io_err(&path, e));
            } else if let Err(e) = yaml.write(&counts, range) {
                failure = Some(e);
            }
            last_flush = Instant::now();
            unflushed = false;
        }
    }
    if let Some(e) = failure {
        return Err(e);
    }
    writer.finish().map_err(|e| io_err(&path, e))?;
    let mut inner = writer.into_inner();
    inner.flush().map_err(|e| io_err(&path, e))?;
    drop(inner);
    yaml.write(&counts, range)?;
    let file_bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
    Ok(BagSummary { counts, time_range: range, file_bytes })
}

/// What `metadata.yaml` is written from.
struct MetadataYaml {
    dir: PathBuf,
    file_name: String,
    topics: Vec<TopicSpec>,
}

impl MetadataYaml {
    /// Writes `metadata.yaml` (to a temporary file, then renamed over the old one).
    fn write(&self, counts: &[u64], range: Option<(u64, u64)>) -> Result<(), BagError> {
        let text = metadata_yaml(&self.file_name, &self.topics, counts, range);
        let path = self.dir.join("metadata.yaml");
        let tmp = self.dir.join(".metadata.yaml.tmp");
        std::fs::write(&tmp, text).map_err(|e| io_err(&tmp, e))?;
        std::fs::rename(&tmp, &path).map_err(|e| io_err(&path, e))
    }
}

/// A YAML double-quoted string.
fn quoted(text: &str) -> String {
    let mut out = String::from("\"");
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            c if (c as u32) < 0x20 => out.push_str(&format!("\\x{:02x}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// The text of rosbag2's `metadata.yaml` (version `METADATA_VERSION`) for one MCAP file.
pub fn metadata_yaml(
    file_name: &str,
    topics: &[TopicSpec],
    counts: &[u64],
    range: Option<(u64, u64)>,
) -> String {
    let (start, end) = range.unwrap_or((0, 0));
    let duration = end - start;
    let total: u64 = counts.iter().sum();
    let mut y = format!(
        "rosbag2_bagfile_information:\n  version: {METADATA_VERSION}\n  storage_identifier: mcap\n  \
         duration:\n    nanoseconds: {duration}\n  starting_time:\n    nanoseconds_since_epoch: {start}\n  \
         message_count: {total}\n  topics_with_message_count:\n"
    );
    for (t, n) in topics.iter().zip(counts) {
        y += &format!(
            "    - topic_metadata:\n        name: {}\n        type: {}\n        serialization_format: cdr\n        \
             offered_qos_profiles: {}\n        type_description_hash: \"\"\n      message_count: {n}\n",
            quoted(&t.name),
            quoted(&t.type_name),
            quoted(&t.qos.profiles_yaml())
        );
    }
    y += &format!(
        "  compression_format: \"\"\n  compression_mode: \"\"\n  relative_file_paths:\n    - {name}\n  files:\n    \
         - path: {name}\n      starting_time:\n        nanoseconds_since_epoch: {start}\n      duration:\n        \
         nanoseconds: {duration}\n      message_count: {total}\n  custom_data: ~\n  ros_distro: \"\"\n",
        name = quoted(file_name)
    );
    y
}

// ----- reading ----------------------------------------------------------------------------------

/// The longest record or chunk a bag reader accepts whatever the file's size, bytes: a chunk's
/// uncompressed content may be longer than the whole compressed file (ours are about 1 MiB,
/// `BagOptions::chunk_size`). A longer length field is taken for damage and refused.
const RECORD_LENGTH_FLOOR: usize = 256 << 20;

/// One recorded message.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedMessage {
    /// Topic name.
    pub topic: String,
    /// Type, `pkg/msg/Type`.
    pub type_name: String,
    /// The channel's `offered_qos_profiles`.
    pub qos_profiles: String,
    /// MCAP sequence (the simulator's step count when it was published).
    pub sequence: u32,
    /// Log time, ns.
    pub log_time: u64,
    /// The CDR message, encapsulation header included.
    pub data: Vec<u8>,
}

impl RecordedMessage {
    /// Decodes the message as `M` (its CDR body after the encapsulation header; little or big
    /// endian as the header says).
    pub fn decode<M: serde::de::DeserializeOwned>(&self) -> Result<M, String> {
        let (header, body) = self.data.split_at(4.min(self.data.len()));
        let result = match header {
            [0, 1, ..] => cdr_encoding::from_bytes::<M, LittleEndian>(body),
            [0, 0, ..] => cdr_encoding::from_bytes::<M, byteorder::BigEndian>(body),
            _ => return Err(format!("{}: not a CDR message (header {header:02x?})", self.topic)),
        };
        result.map(|(m, _)| m).map_err(|e| format!("{}: {e}", self.topic))
    }
}

/// A bag on disk, read as a stream: its run record, topics and messages. Nothing holds the file:
/// each call opens it and reads what it needs (the run record from the file's start, the topics
/// from its summary at the end, the messages chunk by chunk), so memory stays at about a chunk's
/// size whatever the bag's (`tests/allocation.rs`).
pub struct BagReader {
    /// The MCAP file.
    pub path: PathBuf,
    /// Its size when opened, bytes.
    file_bytes: u64,
}

/// A bag's topics and counts, as `tensegrity bag info` prints them.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BagInfo {
    /// The MCAP file.
    pub path: PathBuf,
    /// Its size, bytes.
    pub file_bytes: u64,
    /// Topics with their type and the messages read.
    pub topics: Vec<(TopicSpec, u64)>,
    /// Earliest and latest log time, ns.
    pub time_range: Option<(u64, u64)>,
    /// The run record (`RunInfo`), if the bag has one.
    pub run: Option<RunInfo>,
    /// Why reading stopped before the end of a complete file (a bag cut short), if it did.
    pub cut_short: Option<String>,
}

impl BagReader {
    /// Opens a bag: a rosbag2 directory (its one `.mcap` file, from `metadata.yaml` when present)
    /// or an `.mcap` file.
    pub fn open(path: &Path) -> Result<Self, BagError> {
        let file = if path.is_dir() { Self::mcap_in(path)? } else { path.to_path_buf() };
        let mut f = File::open(&file).map_err(|e| io_err(&file, e))?;
        let file_bytes = f.metadata().map_err(|e| io_err(&file, e))?.len();
        let mut magic = [0u8; 8];
        // what an MCAP file starts and (when closed) ends with
        if file_bytes < 8 || f.read_exact(&mut magic).is_err() || magic[..] != *mcap::MAGIC {
            return Err(BagError::Format { path: file, reason: "not an MCAP file (no MCAP magic)".into() });
        }
        Ok(Self { path: file, file_bytes })
    }

    fn file(&self) -> std::io::Result<File> {
        File::open(&self.path)
    }

    fn mcap_in(dir: &Path) -> Result<PathBuf, BagError> {
        let mut found: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(|e| io_err(dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
            .collect();
        found.sort();
        match found.len() {
            1 => Ok(found.remove(0)),
            0 => Err(BagError::Format { path: dir.to_path_buf(), reason: "holds no .mcap file".into() }),
            n => Err(BagError::Format {
                path: dir.to_path_buf(),
                reason: format!("holds {n} .mcap files; this reader takes bags of one file"),
            }),
        }
    }

    /// True when the file ends with the MCAP magic (it was closed properly).
    pub fn complete(&self) -> bool {
        let mut tail = [0u8; 8];
        self.file_bytes >= 16
            && self
                .file()
                .and_then(|mut f| {
                    f.seek(SeekFrom::End(-8))?;
                    f.read_exact(&mut tail)
                })
                .is_ok()
            && tail[..] == *mcap::MAGIC
    }

    /// How the messages and the run record are read: up to the data end, not requiring the end
    /// magic (a cut bag is read as far as it goes), refusing a record or chunk longer than
    /// `max(file size, RECORD_LENGTH_FLOOR)` instead of allocating for it (a damaged length
    /// field; without the limit, 8 bytes of magic and 5000 random ones panicked on a capacity
    /// overflow).
    fn options(&self) -> LinearReaderOptions {
        let limit = usize::try_from(self.file_bytes).unwrap_or(usize::MAX).max(RECORD_LENGTH_FLOOR);
        LinearReaderOptions::default().with_skip_end_magic(true).with_record_length_limit(limit)
    }

    /// The run record (the metadata record before the first chunk, where our writer puts it;
    /// so a cut bag keeps it too).
    pub fn run(&self) -> Option<RunInfo> {
        let mut file = BufReader::new(self.file().ok()?);
        let mut reader = mcap::sans_io::LinearReader::new_with_options(self.options().with_emit_chunks(true));
        while let Some(event) = reader.next_event() {
            match event.ok()? {
                mcap::sans_io::LinearReadEvent::ReadRequest(n) => {
                    let read = file.read(reader.insert(n)).ok()?;
                    reader.notify_read(read);
                }
                mcap::sans_io::LinearReadEvent::Record { data, opcode } => {
                    match mcap::parse_record(opcode, data) {
                        Ok(mcap::records::Record::Metadata(m)) if m.name == RUN_METADATA => {
                            return Some(m.metadata)
                        }
                        Ok(mcap::records::Record::Chunk { .. }) | Err(_) => return None,
                        Ok(_) => {}
                    }
                }
            }
        }
        None
    }

    /// The summary section (`None` for a bag without one: cut short, or not MCAP enough).
    fn summary(&self) -> Option<mcap::Summary> {
        let mut file = self.file().ok()?;
        // summary records are stored as they are: none is longer than the file
        let limit = usize::try_from(self.file_bytes).unwrap_or(usize::MAX);
        let mut reader = mcap::sans_io::SummaryReader::new_with_options(
            mcap::sans_io::SummaryReaderOptions::default()
                .with_file_size(self.file_bytes)
                .with_record_length_limit(limit),
        );
        while let Some(event) = reader.next_event() {
            match event.ok()? {
                mcap::sans_io::SummaryReadEvent::ReadRequest(n) => {
                    let read = file.read(reader.insert(n)).ok()?;
                    reader.notify_read(read);
                }
                mcap::sans_io::SummaryReadEvent::SeekRequest(to) => {
                    let at = file.seek(to).ok()?;
                    reader.notify_seeked(at);
                }
            }
        }
        reader.finish()
    }

    /// The topics the summary declares, in channel order, also those without messages (empty
    /// for a bag without summary: a cut bag's topics are found by reading, see `info`).
    pub fn declared_topics(&self) -> Vec<TopicSpec> {
        let Some(summary) = self.summary() else { return Vec::new() };
        let mut channels: Vec<_> = summary.channels.values().collect();
        channels.sort_by_key(|c| c.id);
        channels
            .into_iter()
            .map(|c| TopicSpec {
                name: c.topic.clone(),
                type_name: c.schema.as_ref().map(|s| s.name.clone()).unwrap_or_default(),
                qos: parse_qos(c.metadata.get("offered_qos_profiles").map(String::as_str).unwrap_or("")),
            })
            .collect()
    }

    /// Every readable message in file order; reading stops at the first damaged or missing
    /// record, whose reason is the last item (`Err`).
    pub fn messages(&self) -> Box<dyn Iterator<Item = Result<RecordedMessage, String>> + '_> {
        let mut stream = match self.file() {
            Ok(f) => Some(mcap::io::MessageReader::new_with_options(BufReader::new(f), self.options())),
            Err(e) => {
                return Box::new(std::iter::once(Err(format!("cannot read {}: {e}", self.path.display()))))
            }
        };
        Box::new(std::iter::from_fn(move || {
            let s = stream.as_mut()?;
            match s.next()? {
                Ok(m) => Some(Ok(RecordedMessage {
                    topic: m.channel.topic.clone(),
                    type_name: m.channel.schema.as_ref().map(|s| s.name.clone()).unwrap_or_default(),
                    qos_profiles: m.channel.metadata.get("offered_qos_profiles").cloned().unwrap_or_default(),
                    sequence: m.sequence,
                    log_time: m.log_time,
                    data: m.data.into_owned(),
                })),
                Err(e) => {
                    stream = None;
                    Some(Err(cut_reason(&e)))
                }
            }
        }))
    }

    /// Topics, counts, time range and run record, by reading every message (so a cut bag is
    /// counted up to where it can be read).
    pub fn info(&self) -> BagInfo {
        let mut topics: Vec<(TopicSpec, u64)> = self.declared_topics().into_iter().map(|t| (t, 0)).collect();
        let mut range: Option<(u64, u64)> = None;
        let mut cut_short = None;
        for m in self.messages() {
            match m {
                Ok(m) => {
                    let k = match topics.iter().position(|(t, _)| t.name == m.topic) {
                        Some(k) => k,
                        None => {
                            let qos = parse_qos(&m.qos_profiles);
                            topics.push((
                                TopicSpec { name: m.topic.clone(), type_name: m.type_name.clone(), qos },
                                0,
                            ));
                            topics.len() - 1
                        }
                    };
                    topics[k].1 += 1;
                    range =
                        Some(range.map_or((m.log_time, m.log_time), |(a, b)| {
                            (a.min(m.log_time), b.max(m.log_time))
                        }));
                }
                Err(e) => cut_short = Some(e),
            }
        }
        if cut_short.is_none() && !self.complete() {
            cut_short = Some("the file ends without its summary and end magic (not closed)".into());
        }
        BagInfo {
            path: self.path.clone(),
            file_bytes: self.file_bytes,
            topics,
            time_range: range,
            run: self.run(),
            cut_short,
        }
    }
}

/// Words for where a cut bag stops.
fn cut_reason(e: &mcap::McapError) -> String {
    match e {
        mcap::McapError::UnexpectedEof | mcap::McapError::UnexpectedEoc => {
            "the file ends inside a record (cut short: the last chunk was not complete)".into()
        }
        other => format!("damaged record: {other}"),
    }
}

/// QoS from an `offered_qos_profiles` text (depth and durability; anything else is ours).
pub fn parse_qos(text: &str) -> TopicQos {
    let value = |key: &str| {
        text.lines()
            .find_map(|l| l.trim().trim_start_matches("- ").strip_prefix(key))
            .and_then(|v| v.trim().parse::<u32>().ok())
    };
    TopicQos { depth: value("depth:").unwrap_or(0), transient_local: value("durability:") == Some(1) }
}

/// Rewrites a bag whose writer was killed (no summary, no end magic) as a complete one: every
/// message that can be read, the run record, summary, footer and `metadata.yaml`. The original
/// file is kept beside it as `<file>.cut`. Returns what the new bag holds and why the original
/// stopped, or `None` for a bag that is already complete (left as it is). `dir` is the bag's
/// directory (a bare `.mcap` file is refused, untouched).
pub fn reindex(dir: &Path, options: &BagOptions) -> Result<Option<(BagSummary, Option<String>)>, BagError> {
    if !dir.is_dir() {
        // its rebuilt file and metadata go into the bag's directory, which a bare file lacks
        return Err(BagError::Format {
            path: dir.to_path_buf(),
            reason: "not a bag directory: reindex takes the directory that holds the .mcap file".into(),
        });
    }
    let reader = BagReader::open(dir)?;
    if reader.complete() {
        return Ok(None);
    }
    let run = reader.run().unwrap_or_default();
    let topics: Vec<TopicSpec> = reader.info().topics.into_iter().map(|(t, _)| t).collect();
    let original = reader.path.clone();
    let cut = original.with_extension("mcap.cut");
    std::fs::rename(&original, &cut).map_err(|e| io_err(&original, e))?;
    // the reader streams from its file, which now has the other name
    let reader = BagReader::open(&cut)?;
    let rebuilt = dir.join(".reindex");
    let mut writer = BagWriter::create(&rebuilt, topics.clone(), &run, options)?;
    let mut why = None;
    for m in reader.messages() {
        match m {
            Ok(m) => {
                let Some(k) = topics.iter().position(|t| t.name == m.topic) else { continue };
                writer.write_serialized(BagTopic(k), m.sequence, m.log_time, m.data, false)?;
            }
            Err(e) => why = Some(e),
        }
    }
    let summary = writer.finish()?;
    std::fs::rename(rebuilt.join(mcap_file_name(&rebuilt)), &original).map_err(|e| io_err(&original, e))?;
    let file_name = original.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let yaml = MetadataYaml { dir: dir.to_path_buf(), file_name, topics };
    yaml.write(&summary.counts, summary.time_range)?;
    let _ = std::fs::remove_dir_all(&rebuilt);
    Ok(Some((summary, why)))
}
