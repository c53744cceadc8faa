//! Invariant: no scene file, however mangled, crashes, hangs or fools `check` and `statics`. Two
//! thousand deterministic mutations of every bundled scene (deleted keys; 0, negative, NaN,
//! infinite, 1e308, 1e-308 and 2^62 numbers; extra, missing and wrongly typed array entries;
//! emptied, unknown and duplicated names; duplicated tables; unknown keys; byte flips) go through
//! the same calls as `tensegrity check` and `tensegrity statics --json`: none panics; each takes
//! under 5 s; a refusal names the file, a field or line, and a reason; an extra array entry or an
//! unknown key is always refused (nothing is accepted with a value it did not read); and every
//! number in an accepted scene's statics report is finite.

use std::time::{Duration, Instant};

use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::solve::statics::StaticSolver;
use tensegrity::{report, State};
use toml::Value;

/// A small deterministic generator (64-bit LCG), so a failure names a reproducible case.
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        self.0 >> 33
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Path to a value inside a TOML document: keys and array indices.
#[derive(Clone, Debug)]
enum Step {
    Key(String),
    Index(usize),
}

fn leaves(v: &Value, path: &mut Vec<Step>, out: &mut Vec<Vec<Step>>) {
    out.push(path.clone());
    match v {
        Value::Table(t) => {
            for (k, child) in t {
                path.push(Step::Key(k.clone()));
                leaves(child, path, out);
                path.pop();
            }
        }
        Value::Array(a) => {
            for (i, child) in a.iter().enumerate() {
                path.push(Step::Index(i));
                leaves(child, path, out);
                path.pop();
            }
        }
        _ => {}
    }
}

fn at<'a>(v: &'a mut Value, path: &[Step]) -> &'a mut Value {
    path.iter().fold(v, |v, s| match (s, v) {
        (Step::Key(k), Value::Table(t)) => t.get_mut(k).unwrap(),
        (Step::Index(i), Value::Array(a)) => &mut a[*i],
        _ => unreachable!(),
    })
}

/// What a mutation must lead to.
#[derive(Debug, PartialEq)]
enum Expect {
    /// Either refused with a good message or accepted with finite results.
    Anything,
    /// Must be refused.
    Refused,
}

/// One mutation of `doc`, chosen by `rng`; returns the text and what it must lead to.
fn mutate(doc: &Value, text: &str, rng: &mut Lcg) -> (String, Expect, String) {
    let mut paths = Vec::new();
    leaves(doc, &mut Vec::new(), &mut paths);
    let path = paths[1 + rng.below(paths.len() - 1)].clone();
    let mut d = doc.clone();
    let numbers = [
        0.0,
        -1.0,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        1e308,
        -1e308,
        1e-308,
        -1e-308,
        4.611686018427388e18,
    ];
    let kind = rng.below(10);
    let what = format!("kind {kind} at {path:?}");
    let (parent, last) = path.split_at(path.len() - 1);
    let expect = match kind {
        0 => {
            // delete the value
            match (at(&mut d, parent), &last[0]) {
                (Value::Table(t), Step::Key(k)) => {
                    t.remove(k);
                }
                (Value::Array(a), Step::Index(i)) => {
                    a.remove(*i);
                }
                _ => {}
            }
            Expect::Anything
        }
        1..=3 => {
            let v = at(&mut d, &path);
            let x = numbers[rng.below(numbers.len())];
            *v = match v {
                Value::Integer(_) if x.is_finite() && x.abs() < 9e18 => Value::Integer(x as i64),
                Value::Integer(_) => Value::Integer(i64::MAX),
                _ => Value::Float(x),
            };
            Expect::Anything
        }
        4 => {
            // one entry too many in an array of numbers (vectors, ends, inertia)
            let v = at(&mut d, &path);
            match v {
                Value::Array(a) if a.iter().all(|e| e.is_float() || e.is_integer()) && !a.is_empty() => {
                    let len = a.len();
                    a.push(Value::Float(1.0));
                    // inertia takes 1, 3 or 6 numbers: 4 and 7 are both wrong
                    if matches!(len, 1 | 3 | 6)
                        && path.iter().any(|s| matches!(s, Step::Key(k) if k == "inertia"))
                        || len == 3
                        || len == 2
                    {
                        Expect::Refused
                    } else {
                        Expect::Anything
                    }
                }
                Value::Array(a) if !a.is_empty() => {
                    a.pop();
                    Expect::Anything
                }
                other => {
                    *other = Value::Array(vec![other.clone(), Value::Float(1.0)]);
                    Expect::Anything
                }
            }
        }
        5 => {
            let v = at(&mut d, &path);
            *v = match v {
                Value::String(_) => {
                    Value::String(["", "nowhere.point", "a.b.c", "bar0_0"][rng.below(4)].into())
                }
                _ => Value::String("text".into()),
            };
            Expect::Anything
        }
        6 => {
            // an unknown key beside this value, in its table
            let table_path: Vec<Step> = match at(&mut d, &path) {
                Value::Table(_) => path.clone(),
                _ => parent.to_vec(),
            };
            match at(&mut d, &table_path) {
                Value::Table(t) if !t.contains_key("points") || !table_path.is_empty() => {
                    t.insert("unexpected_key".into(), Value::Integer(1));
                    // named points are the one table whose keys are free
                    if table_path.last().is_some_and(|s| matches!(s, Step::Key(k) if k == "points")) {
                        Expect::Anything
                    } else {
                        Expect::Refused
                    }
                }
                _ => Expect::Anything,
            }
        }
        7 => {
            // duplicate a table of an array of tables (duplicate names) or a whole array entry
            if let (Value::Array(a), Step::Index(i)) = (at(&mut d, parent), &last[0]) {
                let e = a[*i].clone();
                a.push(e);
            }
            Expect::Anything
        }
        8 => {
            // replace an array by a scalar or a huge array
            let v = at(&mut d, &path);
            if let Value::Array(a) = v {
                if rng.below(2) == 0 {
                    *v = Value::Float(3.0);
                } else {
                    let e = a.first().cloned().unwrap_or(Value::Float(1.0));
                    *v = Value::Array(vec![e; 2000]);
                }
            }
            Expect::Anything
        }
        _ => {
            // byte flips in the text itself
            let mut bytes = text.as_bytes().to_vec();
            for _ in 0..1 + rng.below(3) {
                let i = rng.below(bytes.len());
                let alphabet = b" =[]{}\".,0123456789e-+abcxyz#\n";
                bytes[i] = alphabet[rng.below(alphabet.len())];
            }
            return (
                String::from_utf8_lossy(&bytes).into_owned(),
                Expect::Anything,
                format!("byte flips ({what})"),
            );
        }
    };
    (toml::to_string(&d).unwrap_or_default(), expect, what)
}

/// `tensegrity check` and `tensegrity statics --json` on `text`, as the CLI runs them; returns
/// whether the scene was accepted.
fn check_and_statics(text: &str, what: &str) -> bool {
    let model = match tensegrity::scene::from_toml(text, "mutant.toml") {
        Ok(m) => m,
        Err(e) => {
            assert_eq!(e.file, "mutant.toml", "{what}");
            assert!(!e.reason.trim().is_empty(), "{what}: no reason: {e}");
            assert!(!e.field.is_empty() || e.line.is_some(), "{what}: names no field or line: {e}");
            return false;
        }
    };
    let _ = report::summary(&model);
    if report::unheld_bodies_note(&model).is_some() {
        return true; // `statics` refuses such scenes by name
    }
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    let reference = report::all_pulley_coordinates(&model, &state, &ws);
    if let Ok(r) = StaticSolver::new(&model).equilibrate(&model, &mut state, &mut ws, &model.solver) {
        assert!(r.residual.is_finite() && r.force_scale.is_finite(), "{what}: {r:?}");
        assert!(r.residual <= 1e-6 * r.force_scale.max(1e-12) * 1.000001, "{what}: claimed with {r:?}");
        evaluate(&model, &state, &mut ws, Tangents::None);
        let json = serde_json::to_string(&(
            report::cable_reports(&model, &state, &ws, &reference),
            report::body_reports(&model, &state),
            report::point_positions(&model, &ws),
        ))
        .unwrap();
        assert!(!json.contains("null"), "{what}: a non-finite number in the statics report");
    }
    true
}

#[test]
fn a_thousand_mutations_of_every_bundled_scene_are_refused_well_or_solved_finitely() {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes");
    let mut scenes: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).collect();
    scenes.sort();
    assert!(scenes.len() >= 4);
    for path in scenes {
        let text = std::fs::read_to_string(&path).unwrap();
        let doc: Value = toml::from_str(&text).unwrap();
        let mut rng = Lcg(0x5eed ^ text.len() as u64);
        let (mut accepted, mut refused, mut slowest) = (0, 0, Duration::ZERO);
        for case in 0..2000 {
            let (mutant, expect, what) = mutate(&doc, &text, &mut rng);
            let what = format!("{} case {case}: {what}", path.display());
            let start = Instant::now();
            let ok = std::panic::catch_unwind(|| check_and_statics(&mutant, &what))
                .unwrap_or_else(|_| panic!("{what}: panicked on\n{mutant}"));
            let took = start.elapsed();
            slowest = slowest.max(took);
            assert!(took < Duration::from_secs(5), "{what}: took {took:?}");
            if expect == Expect::Refused {
                assert!(!ok, "{what}: accepted a value it does not read:\n{mutant}");
            }
            if ok {
                accepted += 1;
            } else {
                refused += 1;
            }
        }
        println!("{}: {accepted} accepted, {refused} refused, slowest {slowest:?}", path.display());
        assert!(refused > 100 && accepted > 10, "the mutations exercise both outcomes");
    }
}
