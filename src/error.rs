//! Error types: scene errors name the file, the line where known, the field path and the reason;
//! solver errors carry where and how the solve failed.

use std::fmt;

/// A number as a person writes it in a message: `0`, `0.1`, `1500`, and exponent form outside
/// 1e-3 to 1e4 (`1e-6`, `2.5e9`), so a limit reads `1e-6 to 0.1`, never `1e-1` or `0e0`.
pub fn readable_number(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-3..1e4).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// `" (did you mean 'x'?)"` for the candidate nearest `word` when it is a likely typo of it (an
/// edit distance of at most a third of its length, at least 1), else an empty string.
pub fn did_you_mean<'a>(word: &str, candidates: impl IntoIterator<Item = &'a str>) -> String {
    let best = candidates.into_iter().map(|c| (edit_distance(word, c), c)).min_by_key(|(d, _)| *d);
    match best {
        Some((d, c)) if d > 0 && d <= (word.chars().count() / 3).max(1) => format!(" (did you mean '{c}'?)"),
        _ => String::new(),
    }
}

/// The Levenshtein distance of `a` and `b` (insertions, deletions and substitutions of chars).
pub fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut diagonal = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let substitute = diagonal + usize::from(ca != *cb);
            diagonal = row[j + 1];
            row[j + 1] = substitute.min(row[j] + 1).min(row[j + 1] + 1);
        }
    }
    row[b.len()]
}

/// A scene that cannot be read or is not a valid structure.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneError {
    /// File the scene came from (or a label such as `<generated prism>`).
    pub file: String,
    /// 1-based line of the offending entry, where known.
    pub line: Option<usize>,
    /// Path of the offending field, e.g. `cables[2].ea` (empty for whole-file errors).
    pub field: String,
    /// What is wrong, with the offending value.
    pub reason: String,
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
        }
        if !self.field.is_empty() {
            write!(f, ": {}", self.field)?;
        }
        write!(f, ": {}", self.reason)
    }
}

impl std::error::Error for SceneError {}

/// `; contact slips: a@g, b@g (beyond its friction cone)` for `SolveError::NoEquilibrium`, or
/// nothing.
fn slipping_words(slipping: &[String]) -> String {
    match slipping {
        [] => String::new(),
        [one] => format!("; contact slips: {one} (no equilibrium holds it inside its friction cone)"),
        many => format!(
            "; contacts slip: {} (no equilibrium holds them inside their friction cones)",
            many.join(", ")
        ),
    }
}

/// A solve that did not reach its goal.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SolveError {
    /// Newton did not converge and the load step could not be cut further.
    #[error(
        "equilibrium not found at t = {time} s (load step {load_step}): residual {residual:.3e} N \
         after {iterations} Newton iterations and {cuts} step cuts{}",
        slipping_words(slipping)
    )]
    NoEquilibrium {
        /// Schedule time of the failing step, s.
        time: f64,
        /// Index of the output load step being solved.
        load_step: usize,
        /// Max-norm of the force residual at the best iterate, N.
        residual: f64,
        /// Newton iterations spent on the last attempt.
        iterations: usize,
        /// Number of times the load step was halved.
        cuts: usize,
        /// The stick-slip contacts (`point@ground`) that slipped at the last iteration: the
        /// solve stopped because no equilibrium holds them inside their friction cones
        /// (`StopReason::ContactSlips`). Empty otherwise.
        slipping: Vec<String>,
    },
    /// A non-finite number appeared; the state was left unchanged.
    #[error("non-finite value in {what} at t = {time} s; state left unchanged")]
    NonFinite {
        /// What became non-finite.
        what: String,
        /// Time, s.
        time: f64,
    },
}
