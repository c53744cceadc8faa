//! `tensegrity replay BAG` and `tensegrity bag info|reindex BAG`: running a bag again and
//! comparing it bit for bit, what a bag holds, and repairing one whose writer was killed.

use std::path::{Path, PathBuf};

use tensegrity::io::record;
use tensegrity::io::record::bag::{self, BagOptions};

use crate::output::*;

use clap::Subcommand;

#[derive(Subcommand)]
pub enum BagCommand {
    /// Topics, types, message counts, duration and the recorded run, like `ros2 bag info`
    /// (also for a bag cut short: counted up to where it can be read).
    Info {
        /// The bag directory (or its .mcap file).
        bag: PathBuf,
    },
    /// Rewrite a bag whose writer was killed (no summary, no end magic) as a complete one that
    /// every reader opens: the messages up to the last complete chunk (the original is kept as
    /// `.mcap.cut`).
    Reindex {
        /// The bag directory.
        bag: PathBuf,
    },
}

/// Runs `bag info` or `bag reindex`.
pub fn run(kind: BagCommand) -> Result<(), String> {
    match kind {
        BagCommand::Info { bag } => {
            let reader = bag::BagReader::open(&bag).map_err(|e| e.to_string())?;
            emit(&format_bag_info(&reader.info()));
            Ok(())
        }
        BagCommand::Reindex { bag } => {
            let Some((summary, why)) =
                bag::reindex(&bag, &BagOptions::default()).map_err(|e| e.to_string())?
            else {
                say!("{}: already complete (summary and end magic): left as it is", bag.display());
                return Ok(());
            };
            say!(
                "{}: rewritten with {} messages{}",
                bag.display(),
                summary.counts.iter().sum::<u64>(),
                why.map_or(String::new(), |w| format!(" (the original stopped: {w})"))
            );
            Ok(())
        }
    }
}

/// `tensegrity replay`: exit status 1 (an error) when the re-run differs.
pub fn replay(bag: &Path, scene: Option<&Path>, out: Option<&Path>) -> Result<(), String> {
    let scene_text = match scene {
        Some(p) => Some((
            std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?,
            p.display().to_string(),
        )),
        None => None,
    };
    let report = record::replay(bag, scene_text.as_ref().map(|(t, l)| (t.as_str(), l.as_str())), out)
        .map_err(|e| e.to_string())?;
    let what = format!(
        "{} messages compared over {} steps ({} command batches, {} resets applied from the bag; /diagnostics not compared)",
        report.compared, report.steps, report.command_batches, report.resets
    );
    if let Some(cut) = &report.cut_short {
        say!("note: the bag stops early ({cut}); compared up to there");
    }
    if report.missing > 0 {
        say!(
            "note: {} messages of the re-run are missing from the bag (its writer dropped them on a full queue); skipped",
            report.missing
        );
    }
    if let Some(out) = out {
        say!("re-run written to {}", out.display());
    }
    match report.difference {
        None => {
            say!("identical: {what}");
            Ok(())
        }
        Some(d) => Err(format!("{d}; {what} before it")),
    }
}

/// A bag time stamp (ns) as `ros2 bag info` shows it: a UTC date and time, then the seconds,
/// `Nov 25 2026 19:02:03.125 UTC (1795633323.125000000 s)`; a simulation-time stamp (an offline
/// run's, before 2001) as seconds only.
fn bag_time(ns: u64) -> String {
    let seconds = format!("{:.9} s", ns as f64 * 1e-9);
    let wall_clock = ns >= 1_000_000_000 * 1_000_000_000;
    match chrono::DateTime::from_timestamp((ns / 1_000_000_000) as i64, (ns % 1_000_000_000) as u32) {
        Some(t) if wall_clock => format!("{} UTC ({seconds})", t.format("%b %e %Y %H:%M:%S%.3f")),
        _ => seconds,
    }
}

/// The table of `tensegrity bag info`.
fn format_bag_info(info: &bag::BagInfo) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let (start, end) = info.time_range.unwrap_or((0, 0));
    let total: u64 = info.topics.iter().map(|(_, n)| n).sum();
    let _ = writeln!(s, "Files:             {}", info.path.display());
    let _ = writeln!(s, "Bag size:          {} bytes", info.file_bytes);
    let _ = writeln!(s, "Storage id:        mcap");
    let _ = writeln!(s, "Duration:          {:.9} s", (end - start) as f64 * 1e-9);
    let _ = writeln!(s, "Start:             {}", bag_time(start));
    let _ = writeln!(s, "End:               {}", bag_time(end));
    let _ = writeln!(s, "Messages:          {total}");
    if let Some(cut) = &info.cut_short {
        let _ = writeln!(s, "Cut short:         {cut} (`tensegrity bag reindex` repairs it)");
    }
    if let Some(run) = &info.run {
        let get = |k: &str| run.get(k).map_or("?", String::as_str);
        let _ = writeln!(
            s,
            "Run:               {} of '{}' ({}), dt {} s, {}",
            get(record::KEY_KIND),
            get("scene_name"),
            get("scene_file"),
            get("dt"),
            get("integrator")
        );
    }
    let width = info.topics.iter().map(|(t, _)| t.name.len()).max().unwrap_or(0);
    let _ = writeln!(s, "Topic information:");
    for (t, n) in &info.topics {
        let _ = writeln!(
            s,
            "  Topic: {:<width$} | Type: {} | Count: {n} | Serialization Format: cdr",
            t.name, t.type_name
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::bag_time;

    #[test]
    fn wall_clock_stamps_show_a_date_and_simulation_stamps_seconds() {
        assert_eq!(
            bag_time(1_795_633_323_125_000_000),
            "Nov 25 2026 19:02:03.125 UTC (1795633323.125000000 s)"
        );
        assert_eq!(bag_time(50_000_000), "0.050000000 s");
    }
}
