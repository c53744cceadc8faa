//! Sensor models (`tensegrity::sensors`): noise statistics against the declared sigma and bias,
//! update rates, delays, quantization, dropouts, orientation noise, seeds that reproduce and
//! seeds that differ, the physics untouched, and careless `[sensors]` tables.

mod common;

use common::model_from_toml;
use tensegrity::io::sink::DiscardSink;
use tensegrity::model::Model;
use tensegrity::sensors::{SensorKind, Sensors};
use tensegrity::sim::{SimSettings, Simulator};

/// A 10 kg load hanging at rest on a rope from a fixed anchor (98.1 N), with `sensors` appended.
fn hanging(sensors: &str) -> Model {
    model_from_toml(&hanging_text(sensors))
}

fn hanging_text(sensors: &str) -> String {
    common::hanging_load() + sensors
}

/// Steps a simulator at rest in its equilibrium `steps` times at 1 ms, updating `sensors` after
/// each step (and once before), and gives `f(sim, sensors)` at every update.
fn run<T>(model: Model, seed: Option<u64>, steps: usize, f: impl FnMut(&Simulator, &Sensors) -> T) -> Vec<T> {
    run_at(model, seed, steps, 1e-3, f)
}

/// `run` at the physics step `dt`, s.
fn run_at<T>(
    model: Model,
    seed: Option<u64>,
    steps: usize,
    dt: f64,
    mut f: impl FnMut(&Simulator, &Sensors) -> T,
) -> Vec<T> {
    let mut sensors = Sensors::new(&model, seed, dt);
    let mut sim = Simulator::at_equilibrium(model, SimSettings { dt, ..SimSettings::default() }).unwrap();
    let mut out = Vec::with_capacity(steps + 1);
    sensors.update(sim.model(), sim.state(), sim.workspace());
    out.push(f(&sim, &sensors));
    for _ in 0..steps {
        sim.step().unwrap();
        sensors.update(sim.model(), sim.state(), sim.workspace());
        out.push(f(&sim, &sensors));
    }
    out
}

fn tension(s: &Sensors) -> f64 {
    s.readings(SensorKind::Tension).unwrap()[0]
}

#[test]
fn tension_noise_has_the_declared_mean_and_spread() {
    let n = 100_000;
    let samples =
        run(hanging("[sensors]\nseed = 3\n[sensors.tension]\nsigma = 0.5\n"), None, n - 1, |sim, s| {
            (tension(s) - sim.workspace().cables[0].tension, sim.workspace().cables[0].tension)
        });
    assert!((samples[n / 2].1 - 98.1).abs() < 1e-4, "the load hangs at rest: {}", samples[n / 2].1);
    let mean = samples.iter().map(|s| s.0).sum::<f64>() / n as f64;
    let var = samples.iter().map(|s| (s.0 - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    assert!(mean.abs() < 4.0 * 0.5 / (n as f64).sqrt(), "mean error {mean} N");
    assert!((var.sqrt() / 0.5 - 1.0).abs() < 0.01, "standard deviation {} N", var.sqrt());
    // with a bias, the mean moves by it
    let biased = run(hanging("[sensors.tension]\nsigma = 0.5\nbias = 2.0\n"), None, 9999, |sim, s| {
        tension(s) - sim.workspace().cables[0].tension
    });
    let mean = biased.iter().sum::<f64>() / biased.len() as f64;
    assert!((mean - 2.0).abs() < 4.0 * 0.5 / 100.0, "biased mean {mean}");
}

#[test]
fn a_100_hz_sensor_updates_once_every_10_steps_and_holds_between() {
    let fresh = run(hanging("[sensors.tension]\nsigma = 0.5\nrate = 100.0\n"), None, 1000, |_, s| {
        (s.is_fresh(SensorKind::Tension), tension(s))
    });
    for (k, (is_fresh, value)) in fresh.iter().enumerate() {
        assert_eq!(*is_fresh, k % 10 == 0, "step {k}");
        if k % 10 != 0 {
            assert_eq!(*value, fresh[k - 1].1, "held at step {k}");
        }
    }
    assert_eq!(fresh.iter().filter(|f| f.0).count(), 101);
}

#[test]
fn the_same_seed_gives_the_same_stream_and_another_seed_another() {
    let text = "[sensors]\nseed = 11\n[sensors.tension]\nsigma = 0.5\n[sensors.position]\nsigma = 1e-3\n";
    let stream = |seed: Option<u64>| {
        run(hanging(text), seed, 500, |_, s| {
            let p = s.readings(SensorKind::Position).unwrap();
            (tension(s).to_bits(), p[5].to_bits())
        })
    };
    let a = stream(None);
    assert_eq!(a, stream(None), "the scene's seed reproduces");
    assert_eq!(a, stream(Some(11)), "the same seed given directly");
    let b = stream(Some(12));
    assert!(a.iter().zip(&b).all(|(x, y)| x.0 != y.0 && x.1 != y.1), "another seed, other values");
    // adding a channel leaves the others' streams as they were
    let more = run(hanging(&(text.to_string() + "[sensors.length]\nsigma = 1e-3\n")), None, 500, |_, s| {
        tension(s).to_bits()
    });
    assert_eq!(more, a.iter().map(|x| x.0).collect::<Vec<_>>());
}

#[test]
fn a_delay_of_k_steps_reports_what_was_measured_k_steps_before() {
    // `delay_s` in seconds at two physics steps, and the step-counted `delay` kept for a release
    for dt in [1e-3, 5e-4] {
        let at = |delay: &str| {
            let model = hanging(&format!("[sensors.tension]\nsigma = 0.5\n{delay}\n"));
            let warnings = model.delay_warnings(dt);
            (run_at(model, None, 200, dt, |_, s| tension(s)), warnings)
        };
        let (now, _) = at("");
        for k in [1, 4, 25] {
            let (late, warnings) = at(&format!("delay_s = {}", k as f64 * dt));
            assert!(late[..=k].iter().all(|v| *v == now[0]), "delay {k}: the first measurement until then");
            assert_eq!(&late[k..], &now[..now.len() - k], "dt {dt}, delay {k}");
            assert!(warnings.is_empty(), "{warnings:?}");
            let (stepped, warnings) = at(&format!("delay = {k}"));
            assert_eq!(stepped, late, "the step-counted field");
            assert!(
                warnings.len() == 1
                    && warnings[0].contains("sensors.tension.delay = ")
                    && warnings[0].contains("delay_s ="),
                "{warnings:?}"
            );
        }
    }
    // 1.4 ms at 1 ms steps: one step, with a warning
    let model = hanging("[sensors.tension]\ndelay_s = 0.0014\n");
    let warnings = model.delay_warnings(1e-3);
    assert!(warnings.len() == 1 && warnings[0].contains("rounded to 1 step ("), "{warnings:?}");
}

#[test]
fn a_lost_reading_is_marked_until_an_update_measures_it_again() {
    // every step an update: a flagged value is the previous step's, an unflagged one is new
    let n = 5000;
    let history = |table: &str| {
        run(hanging(table), None, n, |_, s| {
            (s.measured().to_vec(), s.lost().to_vec(), s.dropped(SensorKind::Tension))
        })
    };
    let every = history("[sensors.tension]\nsigma = 0.5\ndropout = 0.3\n");
    assert!(every.iter().all(|(m, l, _)| m.len() == 1 && l.len() == 1));
    assert!(!every[0].1[0], "the first update is never lost");
    for w in every.windows(2) {
        let ((before, _, _), (now, lost, _)) = (&w[0], &w[1]);
        assert_eq!(lost[0], now[0] == before[0], "held exactly when flagged: {before:?} -> {now:?}");
    }
    let flagged = every.iter().filter(|(_, l, _)| l[0]).count() as u64;
    assert_eq!(flagged, every.last().unwrap().2, "one flag per value lost");
    assert!((flagged as f64 / n as f64 - 0.3).abs() < 0.03, "{flagged} of {n}");
    // at 100 Hz the flag holds with the value until the next update
    let slow = history("[sensors.tension]\nsigma = 0.5\ndropout = 0.3\nrate = 100.0\n");
    for (k, w) in slow.windows(2).enumerate() {
        if (k + 1) % 10 != 0 {
            assert_eq!(w[0].0, w[1].0, "held between updates");
            assert_eq!(w[0].1, w[1].1, "and so is its flag");
        }
    }
    assert!(slow.iter().any(|(_, l, _)| l[0]) && slow.iter().any(|(_, l, _)| !l[0]));
    // a delay of 5 steps delays the flag with the value
    let late = history("[sensors.tension]\nsigma = 0.5\ndropout = 0.3\ndelay_s = 0.005\n");
    assert_eq!(
        late[5..].iter().map(|h| h.1[0]).collect::<Vec<_>>(),
        every[..=n - 5].iter().map(|h| h.1[0]).collect::<Vec<_>>()
    );
    // an orientation's four values are lost together; a position's three one by one
    let bodies = history("[sensors.orientation]\nsigma = 0.01\ndropout = 0.3\n[sensors.position]\nsigma = 1e-3\ndropout = 0.3\n");
    let model = hanging("[sensors.orientation]\n[sensors.position]\n");
    let layout: Vec<_> = tensegrity::sensors::layout(&model).collect();
    let (_, q0, qn) = *layout.iter().find(|(k, _, _)| *k == SensorKind::Orientation).unwrap();
    let (_, x0, xn) = *layout.iter().find(|(k, _, _)| *k == SensorKind::Position).unwrap();
    let mut mixed = false;
    for (_, lost, _) in &bodies {
        assert!(lost[q0..q0 + qn].chunks_exact(4).all(|q| q.iter().all(|l| *l == q[0])));
        mixed |= lost[x0..x0 + xn].chunks_exact(3).any(|x| x.iter().any(|l| *l != x[0]));
    }
    assert!(mixed, "a position's coordinates are lost one by one");
    // no sensors, no flags
    let plain = run(hanging(""), None, 3, |_, s| s.lost().len());
    assert!(plain.iter().all(|l| *l == 0));
}

#[test]
fn quantization_dropout_and_orientation_noise() {
    let values =
        run(hanging("[sensors.rest_length]\nsigma = 1e-4\nresolution = 1e-3\n"), None, 300, |_, s| {
            s.readings(SensorKind::RestLength).unwrap()[0]
        });
    for v in &values {
        assert!(((v / 1e-3) - (v / 1e-3).round()).abs() < 1e-9, "{v} is not a multiple of 1 mm");
    }
    // dropouts: about the declared fraction lost, each loss holding the last value
    let p = 0.2;
    let n = 20_000;
    let (readings, dropped) = {
        let mut last = 0;
        let r = run(hanging(&format!("[sensors.tension]\nsigma = 0.5\ndropout = {p}\n")), None, n, |_, s| {
            let lost = s.dropped(SensorKind::Tension) > last;
            last = s.dropped(SensorKind::Tension);
            (tension(s), lost)
        });
        (r.iter().map(|x| x.0).collect::<Vec<_>>(), r.iter().map(|x| x.1).collect::<Vec<_>>())
    };
    let lost = dropped.iter().filter(|d| **d).count() as f64 / n as f64;
    let sd = (p * (1.0 - p) / n as f64).sqrt();
    assert!((lost - p).abs() < 5.0 * sd, "lost {lost}");
    for k in 1..readings.len() {
        if dropped[k] {
            assert_eq!(readings[k], readings[k - 1], "a lost update holds at {k}");
        }
    }
    // orientation noise: unit quaternions whose error angle has E[angle^2] = 3 sigma^2
    let sigma = 0.01;
    let angles =
        run(hanging(&format!("[sensors.orientation]\nsigma = {sigma}\n")), None, 20_000, |sim, s| {
            let q = s.readings(SensorKind::Orientation).unwrap();
            let q = &q[4..8]; // the load's
            let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
            assert!((norm - 1.0).abs() < 1e-12);
            let truth = sim.state().poses[1].rotation;
            let measured =
                nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
            truth.angle_to(&measured).powi(2)
        });
    let mean = angles.iter().sum::<f64>() / angles.len() as f64;
    assert!((mean / (3.0 * sigma * sigma) - 1.0).abs() < 0.03, "E[angle^2] = {mean}");
}

#[test]
fn sensors_never_touch_the_physics() {
    let with = run(
        hanging("[sensors.tension]\nsigma = 5.0\n[sensors.position]\nsigma = 0.1\n"),
        None,
        300,
        |sim, _| sim.state().clone(),
    );
    let without = run(hanging(""), None, 300, |sim, _| sim.state().clone());
    assert_eq!(with, without);
}

#[test]
fn careless_sensors_are_refused_naming_the_field() {
    for (table, field, reason) in [
        ("[sensors.tension]\nsigma = -1.0", "sensors.tension.sigma", ">= 0"),
        ("[sensors.tension]\nsigma = nan", "sensors.tension.sigma", "finite"),
        ("[sensors.length]\nrate = 0.0", "sensors.length.rate", "positive"),
        ("[sensors.length]\ndropout = 1.0", "sensors.length.dropout", "[0, 1)"),
        ("[sensors.position]\nbias = inf", "sensors.position.bias", "finite"),
        ("[sensors.orientation]\nbias = 0.1", "sensors.orientation.bias", "no bias"),
        ("[sensors.tension]\ndelay = 1000000", "sensors.tension.delay", "at most"),
        ("[sensors.tension]\ndelay_s = -1e-3", "sensors.tension.delay_s", ">= 0"),
        ("[sensors.tension]\ndelay_s = 2.0", "sensors.tension.delay_s", "[0, 1] s"),
        ("[sensors.tension]\ndelay_s = 0.01\ndelay = 10", "sensors.tension.delay", "not both"),
        ("[sensors.voltage]\nsigma = 1.0", "sensors", "voltage"),
        ("[sensors]\nseed = -3", "sensors", ""),
    ] {
        let text = hanging_text(table);
        let err = tensegrity::scene::from_toml(&text, "careless.toml").expect_err(table).to_string();
        assert!(err.contains("careless.toml"), "{err}");
        assert!(err.contains(field), "{table}: {err}");
        assert!(err.contains(reason), "{table}: {err}");
    }
}

#[test]
fn the_nodes_sensor_seed_parameter_overrides_the_scenes_and_a_reset_starts_the_stream_over() {
    use tensegrity::io::node::{params::NodeParams, NodeCore};
    let model = hanging("[sensors]\nseed = 21\n[sensors.tension]\nsigma = 0.5\n");
    let stream = |seed: Option<u64>, reset: bool| {
        let params = NodeParams { start_paused: true, sensor_seed: seed, ..NodeParams::default() };
        let mut core = NodeCore::new(model.clone(), params).unwrap();
        let mut out = vec![tension(core.sensors())];
        for _ in 0..2 {
            let ticket = core.request_steps(50, &mut DiscardSink).unwrap();
            assert!(ticket > 0);
            for k in 0..200 {
                core.tick(std::time::Duration::from_millis(k), &mut DiscardSink);
            }
            out.push(tension(core.sensors()));
            if reset {
                core.reset(&mut DiscardSink);
                assert_eq!(tension(core.sensors()), out[0], "a reset measures the start again");
            }
        }
        assert_eq!(core.stats().steps, 100);
        out
    };
    let scene = stream(None, false);
    assert_eq!(scene, stream(Some(21), false), "the parameter at the scene's seed");
    assert!(stream(Some(22), false).iter().zip(&scene).all(|(a, b)| a != b));
    let with_resets = stream(None, true);
    assert_eq!(with_resets[1], with_resets[2], "after a reset the same 50 steps measure the same");
    assert_eq!(with_resets[1], scene[1]);
}

#[test]
fn the_nodes_physics_dt_keeps_a_delay_in_seconds() {
    // at the node's physics_dt of 0.5 ms, 2 ms are 4 steps: as the step-counted delay of 4, not 2
    use tensegrity::io::node::{params::NodeParams, NodeCore};
    let stream = |delay: &str| {
        let model = hanging(&format!("[sensors.tension]\nsigma = 0.5\n{delay}\n"));
        let params = NodeParams { start_paused: true, physics_dt: Some(5e-4), ..NodeParams::default() };
        let mut core = NodeCore::new(model, params).unwrap();
        let mut out = Vec::new();
        for _ in 0..20 {
            core.request_steps(1, &mut DiscardSink).unwrap();
            for k in 0..4 {
                core.tick(std::time::Duration::from_millis(k), &mut DiscardSink);
            }
            out.push(tension(core.sensors()));
        }
        assert_eq!(core.stats().steps, 20);
        out
    };
    let seconds = stream("delay_s = 0.002");
    assert_eq!(seconds, stream("delay = 4"));
    assert_ne!(seconds, stream("delay = 2"));
}

#[test]
fn an_imu_on_a_swinging_bar_reads_its_closed_form_rate_and_specific_force() {
    // a uniform rod about its end (I = m L^2 / 3), at theta below level: theta' = sqrt(3 g sin
    // theta / L), theta'' = 3 g cos theta / (2 L); its centre accelerates by L/2 (theta'' along the
    // swing + theta'^2 towards the pin), and the accelerometer reads R^T (a - g)
    // config/examples/imu.toml: a 1 kg, 1 m bar pinned at one end, released level in the x-y plane
    let (g, len, dt) = (9.81, 1.0, 1e-4);
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/examples/imu.toml")).unwrap();
    let model = model_from_toml(&text);
    let mut sensors = Sensors::new(&model, None, dt);
    let settings = SimSettings { dt, ..SimSettings::default() };
    let mut sim = Simulator::new(model, settings).unwrap();
    sensors.update(sim.model(), sim.state(), sim.workspace());
    // the truth (the example's sensors are noisy: their statistics are the other tests')
    let truth = |s: &Sensors, k: usize| nalgebra::Vector3::from_column_slice(&s.imu_truth()[k..k + 3]);
    // at rest before the first step: gravity alone, along the bar's axes
    let f0 = truth(&sensors, 3);
    let up = sim.state().poses[0].rotation.inverse_transform_vector(&nalgebra::Vector3::new(0.0, g, 0.0));
    assert!((f0 - up).norm() < 1e-12, "{f0:?}");
    let (mut worst_rate, mut worst_force, mut at_bottom) = (0.0f64, 0.0f64, None);
    while sim.state().time < 0.6 {
        sim.step().unwrap();
        sensors.update(sim.model(), sim.state(), sim.workspace());
        let pose = sim.state().poses[0];
        let axis = pose.rotation * nalgebra::Vector3::z(); // from the pin to the tip
        let theta = (-axis.y).atan2(axis.x);
        if !(0.05..=1.5).contains(&theta) {
            continue;
        }
        let rate = (3.0 * g * theta.sin() / len).sqrt();
        let accel = 3.0 * g * theta.cos() / (2.0 * len);
        // swinging down: clockwise about z
        let swing = nalgebra::Vector3::new(axis.y, -axis.x, 0.0);
        let a = 0.5 * len * (accel * swing - rate * rate * axis);
        let f = a - nalgebra::Vector3::new(0.0, -g, 0.0);
        let gyro = pose.rotation * truth(&sensors, 0);
        let measured = pose.rotation * truth(&sensors, 3);
        // a fresh reading (200 Hz) is the truth with the declared noise and bias
        if sensors.is_fresh(SensorKind::Gyro) {
            let read = sensors.readings(SensorKind::Gyro).unwrap();
            let off = (nalgebra::Vector3::from_column_slice(read) - truth(&sensors, 0)).amax();
            assert!(off < 0.002 + 6.0 * 0.01, "gyro reads {read:?}");
            let read = sensors.readings(SensorKind::Accelerometer).unwrap();
            let off = (nalgebra::Vector3::from_column_slice(read) - truth(&sensors, 3)).amax();
            assert!(off < 6.0 * 0.05, "accelerometer reads {read:?}");
        }
        worst_rate = worst_rate.max((gyro - nalgebra::Vector3::new(0.0, 0.0, -rate)).norm() / rate);
        worst_force = worst_force.max((measured - f).norm() / g);
        if theta > 1.5 - 1e-2 {
            at_bottom.get_or_insert(measured.norm());
        }
    }
    assert!(worst_rate < 1e-3, "gyro off its closed form by {worst_rate} (relative)");
    assert!(worst_force < 1e-3, "accelerometer off its closed form by {worst_force} g");
    // near the bottom: 1.5 g of centripetal acceleration plus gravity's 1 g, along the bar
    let bottom = at_bottom.expect("the bar reached the bottom");
    assert!((bottom / (2.5 * g) - 1.0).abs() < 1e-2, "{bottom} m/s^2 near the bottom");
}

#[test]
fn an_imu_reads_zero_in_free_fall_and_one_g_up_at_rest() {
    let text = hanging_text("[sensors.gyro]\n[sensors.accelerometer]\n");
    // the hanging load at rest: +9.81 m/s^2 up, no rotation; the ceiling too
    let readings = run(model_from_toml(&text), None, 50, |_, s| {
        (
            s.readings(SensorKind::Gyro).unwrap().to_vec(),
            s.readings(SensorKind::Accelerometer).unwrap().to_vec(),
        )
    });
    for (gyro, accel) in &readings {
        assert!(gyro.iter().all(|w| *w == 0.0), "{gyro:?}");
        for body in accel.chunks_exact(3) {
            assert!(
                body[0].abs() < 1e-9 && body[1].abs() < 1e-9 && (body[2] - 9.81).abs() < 1e-6,
                "{body:?}"
            );
        }
    }
    // cut loose (no rope): the load falls, and its accelerometer reads nothing
    let start = text.find("[[cables]]").unwrap();
    let end = text.find("[sensors.gyro]").unwrap();
    let free = model_from_toml(&format!("{}{}", &text[..start], &text[end..]));
    let mut sensors = Sensors::new(&free, None, 1e-3);
    let mut sim = Simulator::new(free, SimSettings::default()).unwrap();
    sensors.update(sim.model(), sim.state(), sim.workspace());
    for _ in 0..100 {
        sim.step().unwrap();
        sensors.update(sim.model(), sim.state(), sim.workspace());
        let f = &sensors.readings(SensorKind::Accelerometer).unwrap()[3..6];
        assert!(f.iter().all(|x| x.abs() < 1e-9), "free fall reads {f:?}");
    }
    assert!(sim.state().velocities[2] < -0.9, "it fell");
}
