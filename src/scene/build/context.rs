//! Where build errors point, and the range checks every stage shares: takes the scene's file name
//! and text, gives `SceneError`s with the field path and line.

use crate::error::{readable_number, SceneError};
use crate::scene::spec::{self, limits};

pub(super) struct Ctx<'a> {
    pub(super) file: &'a str,
    pub(super) text: Option<&'a str>,
}

impl Ctx<'_> {
    pub(crate) fn err(
        &self,
        array: &str,
        index: usize,
        field: &str,
        reason: impl Into<String>,
    ) -> SceneError {
        let path =
            if field.is_empty() { format!("{array}[{index}]") } else { format!("{array}[{index}].{field}") };
        SceneError {
            file: self.file.to_string(),
            line: self.text.and_then(|t| spec::locate(t, array, index, field)),
            field: path,
            reason: reason.into(),
        }
    }
    pub(crate) fn top(&self, field: &str, reason: impl Into<String>) -> SceneError {
        // the key itself, else the table it names (`[deployment]`, `[solver]`)
        let line = self.text.and_then(|t| {
            let top = field.split('.').next().unwrap_or(field);
            t.lines()
                .position(|l| l.trim_start().starts_with(field))
                .or_else(|| t.lines().position(|l| l.trim() == format!("[{top}]")))
                .map(|i| i + 1)
        });
        SceneError { file: self.file.into(), line, field: field.into(), reason: reason.into() }
    }
}

/// `x` when it lies in `[lo, hi]`, else the reason (with the unit `unit`).
pub(super) fn in_range(x: f64, (lo, hi): (f64, f64), unit: &str) -> Result<f64, String> {
    if !x.is_finite() {
        Err(format!("must be finite, got {x}"))
    } else if lo > 0.0 && x <= 0.0 {
        Err(format!("must be positive, got {}", readable_number(x)))
    } else if lo == 0.0 && x < 0.0 {
        Err(format!("must be >= 0, got {}", readable_number(x)))
    } else if x < lo || x > hi {
        Err(format!(
            "must be in [{}, {}]{}, got {}",
            readable_number(lo),
            readable_number(hi),
            if unit.is_empty() { String::new() } else { format!(" {unit}") },
            readable_number(x)
        ))
    } else {
        Ok(x)
    }
}

/// `v` when every entry is finite and within `max` in magnitude.
pub(super) fn bounded3(v: &[f64; 3], max: f64, unit: &str) -> Result<(), String> {
    match v.iter().find(|x| !(x.is_finite() && x.abs() <= max)) {
        None => Ok(()),
        Some(x) if !x.is_finite() => Err(format!("must be finite, got {v:?}")),
        Some(x) => Err(format!(
            "entries must be within +-{} {unit}, got {}",
            readable_number(max),
            readable_number(*x)
        )),
    }
}

pub(super) fn mass(x: Option<f64>) -> Result<f64, String> {
    match x {
        None => Err("missing (required for this kind)".into()),
        Some(m) => in_range(m, limits::MASS, "kg"),
    }
}

/// The delay a scene gives in seconds (`seconds`, the `{field}_s` key) or in physics steps
/// (`steps`, the step-counted `field`, kept for one release): at most one of them, seconds in
/// `limits::DELAY_S`, steps up to `limits::COMMAND_DELAY`; zero when neither is given.
/// `err(field, reason)` names the key.
pub(super) fn delay(
    seconds: Option<f64>,
    steps: Option<usize>,
    field: &str,
    err: impl Fn(&str, String) -> SceneError,
) -> Result<crate::model::Delay, SceneError> {
    use crate::model::Delay;
    use crate::scene::spec::limits;
    let field_s = format!("{field}_s");
    match (seconds, steps) {
        (Some(_), Some(_)) => Err(err(
            field,
            format!("give {field_s} (seconds) or {field} (steps, kept for one release), not both"),
        )),
        (Some(s), None) => {
            Ok(Delay::Seconds(in_range(s, limits::DELAY_S, "s").map_err(|r| err(&field_s, r))?))
        }
        (None, Some(k)) if k > limits::COMMAND_DELAY => Err(err(
            field,
            format!(
                "must be at most {} steps, got {k} (better: {field_s}, in seconds)",
                limits::COMMAND_DELAY
            ),
        )),
        (None, Some(k)) => Ok(Delay::Steps(k)),
        (None, None) => Ok(Delay::Steps(0)),
    }
}
