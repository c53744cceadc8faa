//! Invariant: the dynamic-deployment command line produces what the README promises: `deploy
//! --dynamic` writes a time history with energies and step statistics, `study` writes the
//! quasi-static path, one history per actuation time, a summary whose deviations shrink as the
//! actuation slows, and PNG and SVG plots, and `bench work-precision` writes its table and plot with
//! errors that fall as the step falls. The 1 % threshold is interpolated between bracketing runs.

use std::path::PathBuf;
use std::process::Command;

mod common;
use common::scratch;

use tensegrity::study::one_percent_threshold;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn tensegrity(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_tensegrity")).args(args).current_dir(root()).output().expect("runs")
}

#[test]
fn threshold_is_interpolated_between_bracketing_runs() {
    assert_eq!(one_percent_threshold(&[1.0, 2.0], &[0.001, 0.0005]), None);
    assert_eq!(one_percent_threshold(&[1.0, 2.0], &[0.05, 0.02]), Some(f64::INFINITY));
    let t = one_percent_threshold(&[0.1, 1.0], &[0.1, 0.001]).unwrap();
    assert!((t - 0.1f64.sqrt()).abs() < 1e-12, "{t}");
}

#[test]
fn deploy_dynamic_writes_a_time_history() {
    let dir = scratch("dyn");
    let csv = dir.join("prism3.csv");
    let out = tensegrity(&[
        "deploy",
        "config/scenes/prism3.toml",
        "--dynamic",
        "--dt",
        "2e-3",
        "--duration",
        "0.2",
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 1 + 1 + 100, "header, the start at t = 0, one row per step");
    assert!(lines[1].starts_with("0.000000000,"));
    let header: Vec<&str> = lines[0].split(',').collect();
    for col in [
        "time_s",
        "ring_tension_N",
        "ring_rest_length_m",
        "bar0_0.b_z_m",
        "kinetic_J",
        "actuator_work_J",
        "damping_loss_J",
        "newton_iterations",
        "rejected",
        "wall_us",
    ] {
        assert!(header.contains(&col), "missing column {col}");
    }
    let last: Vec<f64> = lines[101].split(',').map(|v| v.parse().unwrap()).collect();
    assert!((last[0] - 0.2).abs() < 1e-9);
    assert!(last.iter().all(|v| v.is_finite()));
    // symplectic Euler above its limit is refused with the limit in the message
    let out = tensegrity(&[
        "deploy",
        "config/scenes/prism3.toml",
        "--dynamic",
        "--integrator",
        "euler",
        "--dt",
        "0.05",
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("stability limit"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn study_writes_tables_histories_and_plots() {
    let dir = scratch("study");
    let out = tensegrity(&[
        "study",
        "config/scenes/tbar.toml",
        "--ramp-times",
        "0.05,0.5,3",
        "--settle",
        "0.3",
        "--dt",
        "2e-3",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for f in [
        "quasi_static.csv",
        "dynamic_T0.05.csv",
        "dynamic_T0.5.csv",
        "dynamic_T3.csv",
        "summary.csv",
        "summary.md",
        "deviation.png",
        "deviation.svg",
        "histories.png",
        "histories.svg",
    ] {
        let meta = std::fs::metadata(dir.join(f)).unwrap_or_else(|_| panic!("missing {f}"));
        assert!(meta.len() > 100, "{f} is nearly empty");
    }
    let summary = std::fs::read_to_string(dir.join("summary.csv")).unwrap();
    let dev: Vec<f64> =
        summary.lines().skip(1).map(|l| l.split(',').nth(2).unwrap().parse().unwrap()).collect();
    assert_eq!(dev.len(), 3);
    assert!(
        summary.starts_with("ramp_time_s,peak_tension_N,tension_deviation_percent,"),
        "units in every header"
    );
    assert!(
        dev[0] > 1.0 && dev[0] > dev[1] && dev[1] > dev[2].abs(),
        "tension deviations in percent {dev:?}"
    );
    let png = std::fs::read(dir.join("deviation.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    // real log axes: decade ticks labelled in data units, no "log10" in an axis title
    let svg = std::fs::read_to_string(dir.join("deviation.svg")).unwrap();
    assert!(svg.contains("<svg") && !svg.contains("log10"), "axis titles in log10 units");
    assert!(svg.contains("\n0.1\n") && svg.contains("\n1\n"), "decade tick labels as numbers");
    // colour-blind-safe palette for the two deviations
    assert!(svg.contains("#0072B2") && svg.contains("#D55E00"), "Okabe-Ito palette");
    // the runs, ordered by actuation time, one colour each (plasma from #0D0887); the
    // quasi-static reference is the grey band drawn first, under them
    let svg = std::fs::read_to_string(dir.join("histories.svg")).unwrap();
    let grey = svg.find("#AFAFAF").expect("the quasi-static band");
    let first_run = svg.find("#0D0887").expect("the first run in plasma");
    assert!(grey < first_run, "the band under the runs");
    let colours: std::collections::BTreeSet<&str> = svg
        .split("stroke=\"#")
        .skip(1)
        .map(|t| &t[..6])
        .filter(|c| *c != "000000" && *c != "AFAFAF")
        .collect();
    assert!(colours.len() >= 3, "one colour per run: {colours:?}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn study_without_ramp_times_spans_the_scenes_own_actuation_time() {
    use tensegrity::study::{default_ramp_times, scale_schedule};
    let mut model = tensegrity::scene::load(&root().join("config/scenes/tbar.toml")).unwrap();
    assert_eq!(default_ramp_times(&model).unwrap(), vec![0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0]);
    scale_schedule(&mut model, 0.3);
    assert_eq!(default_ramp_times(&model).unwrap(), vec![0.006, 0.015, 0.03, 0.06, 0.15, 0.3, 0.6, 1.5]);
    let atwood = tensegrity::scene::load(&root().join("config/scenes/atwood.toml")).unwrap();
    assert!(default_ramp_times(&atwood).unwrap_err().contains("no deployment schedule"));

    let dir = scratch("study-default");
    let out = tensegrity(&[
        "study",
        "config/scenes/tbar.toml",
        "--settle",
        "0.2",
        "--dt",
        "4e-3",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let summary = std::fs::read_to_string(dir.join("summary.csv")).unwrap();
    let times: Vec<&str> = summary.lines().skip(1).map(|l| l.split(',').next().unwrap()).collect();
    assert_eq!(times, ["0.02", "0.05", "0.1", "0.2", "0.5", "1", "2", "5"], "{summary}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn work_precision_bench_writes_a_table_with_converging_errors() {
    let dir = scratch("wp");
    let out = tensegrity(&[
        "bench",
        "work-precision",
        "config/scenes/tbar.toml",
        "--reference-dt",
        "1e-4",
        "--repeats",
        "1",
        "--duration",
        "0.3",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let table = std::fs::read_to_string(dir.join("work_precision.csv")).unwrap();
    let header: Vec<&str> = table.lines().next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (dt, error, wall) = (column("dt_s"), column("max_point_error_m"), column("median_wall_time_s"));
    let rows = |prefix: &str| -> Vec<(f64, f64, f64)> {
        table
            .lines()
            .skip(1)
            .filter(|l| l.starts_with(prefix))
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                (f[dt].parse().unwrap_or(0.0), f[error].parse().unwrap(), f[wall].parse().unwrap())
            })
            .collect()
    };
    let ga = rows("generalized-alpha(rho=0.8),");
    assert_eq!(ga.len(), 6);
    assert!(ga.windows(2).all(|w| w[1].1 < w[0].1), "errors fall as the step falls: {ga:?}");
    assert!(ga.iter().all(|r| r.2 > 0.0), "every run was timed");
    // every integrator, and the error-controlled runs, whose errors fall as the tolerance does
    for name in ["symplectic-euler,", "rk4,", "dormand-prince,"] {
        assert!(!rows(name).is_empty(), "{name}");
    }
    // the error-controlled runs deliver their tolerances (1e-3 down to 1e-9 m, in order); at
    // loose ones the stability limit, not the tolerance, holds the step, and the errors sit far
    // below it, so they fall with the tolerance only from where it binds
    let controlled = rows("dormand-prince (tol),");
    assert_eq!(controlled.len(), 7, "{controlled:?}");
    for (k, row) in controlled.iter().enumerate() {
        let tolerance = 10f64.powi(-3 - k as i32);
        assert!(row.1 <= 3.0 * tolerance, "tolerance {tolerance:e}: error {:e}", row.1);
    }
    assert!(controlled[4..].windows(2).all(|w| w[1].1 < w[0].1), "{controlled:?}");
    let md = std::fs::read_to_string(dir.join("work_precision.md")).unwrap();
    assert!(md.contains("Cheapest run with at most 1e-4 m error") && md.contains("x the tolerance"), "{md}");
    for f in ["work_precision.md", "work_precision.png", "work_precision.svg"] {
        assert!(dir.join(f).exists(), "missing {f}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn step_and_scaling_benches_time_real_steps_and_refuse_bad_targets() {
    let out = tensegrity(&["bench", "steps", "config/scenes/prism3.toml", "--steps", "200"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    let median: f64 = text.split("median ").nth(1).unwrap().split(' ').next().unwrap().parse().unwrap();
    let newton: f64 = text.split("Newton ").nth(1).unwrap().split('/').next().unwrap().parse().unwrap();
    assert!(median > 0.0 && newton >= 1.0, "a deploying prism needs Newton work every step: {text}");
    for bad in ["tower:spiral:4", "tower:classical:0", "tower:helical", "no/such/scene.toml"] {
        let out = tensegrity(&["bench", "steps", bad, "--steps", "5"]);
        assert!(!out.status.success(), "{bad} accepted");
    }

    let dir = scratch("scaling");
    let out = tensegrity(&[
        "bench",
        "scaling",
        "--stages",
        "2,8,16",
        "--steps",
        "20",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let csv = std::fs::read_to_string(dir.join("scaling.csv")).unwrap();
    let rows: Vec<Vec<String>> =
        csv.lines().skip(1).map(|l| l.split(',').map(String::from).collect()).collect();
    assert_eq!(rows.len(), 9, "3 families x 3 sizes:\n{csv}");
    for r in &rows {
        let sparse: f64 = r[9].parse().unwrap();
        assert!(sparse > 0.0, "every run timed: {r:?}");
    }
    let md = std::fs::read_to_string(dir.join("scaling.md")).unwrap();
    assert_eq!(md.matches("sparse step time ~ stages^").count(), 3, "{md}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn machine_bench_reports_both_measurements_and_refuses_bad_arguments() {
    let out = tensegrity(&["bench", "machine", "--seconds", "0.05", "--period", "0.002"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    let wakeups: u64 = text.split(": ").nth(1).unwrap().split(' ').next().unwrap().parse().unwrap();
    // 25 deadlines 2 ms apart in 50 ms, fewer when the machine was more than a period late
    assert!((1..=26).contains(&wakeups), "{text}");
    assert!(text.contains("deadlines 2000 us apart") && text.contains("never sleeping for 0.05 s"), "{text}");
    for bad in [["--period", "0"], ["--period", "nan"], ["--seconds", "0"], ["--seconds", "inf"]] {
        let out = tensegrity(&["bench", "machine", bad[0], bad[1]]);
        assert!(!out.status.success(), "{bad:?} accepted");
        assert!(
            String::from_utf8_lossy(&out.stderr).contains(bad[0]),
            "{bad:?}: the message names the option"
        );
    }
    // a measurement shorter than one period would sleep past its own end
    let out = tensegrity(&["bench", "machine", "--seconds", "0.2", "--period", "1"]);
    assert!(!out.status.success(), "a run shorter than its period accepted");
    assert!(String::from_utf8_lossy(&out.stderr).contains("at least one --period"));
}

/// Parallel studies and benchmarks give exactly the serial results: every run is independent and
/// deterministic, so only the wall-time columns may differ (the files are compared with them
/// blanked out).
#[test]
fn parallel_runs_give_exactly_the_serial_results() {
    use tensegrity::sim::SimSettings;
    use tensegrity::solve::dynamics::Integrator;
    use tensegrity::study::{work_precision, RunConfig, WorkPrecisionSettings};
    let model = tensegrity::scene::load(&root().join("config/scenes/tbar.toml")).unwrap();
    // blank the named columns of a CSV
    let without = |text: &str, drop: &[&str]| -> Vec<String> {
        let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
        let keep: Vec<usize> = (0..header.len()).filter(|i| !drop.contains(&header[*i])).collect();
        text.lines()
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                keep.iter().map(|&i| f[i]).collect::<Vec<_>>().join(",")
            })
            .collect()
    };
    let (serial, parallel) = (scratch("study-serial"), scratch("study-parallel"));
    let times = [0.05, 0.2, 0.5, 1.0];
    let settings = SimSettings { dt: 2e-3, ..Default::default() };
    let a = tensegrity::study::deployment_study(&model, &times, None, settings, 0.2, 1, &serial).unwrap();
    let b = tensegrity::study::deployment_study(&model, &times, None, settings, 0.2, 2, &parallel).unwrap();
    for (x, y) in a.rows.iter().zip(&b.rows) {
        assert_eq!((x.peak_tension, x.peak_displacement), (y.peak_tension, y.peak_displacement));
    }
    let read = |d: &PathBuf, f: &str| std::fs::read_to_string(d.join(f)).unwrap();
    assert_eq!(
        without(&read(&serial, "summary.csv"), &["wall_time_s"]),
        without(&read(&parallel, "summary.csv"), &["wall_time_s"])
    );
    for t in times {
        let f = format!("dynamic_T{t}.csv");
        assert_eq!(
            without(&read(&serial, &f), &["wall_us"]),
            without(&read(&parallel, &f), &["wall_us"]),
            "{f}"
        );
    }
    let ga = Integrator::GeneralizedAlpha { rho_inf: 0.8 };
    let configs = [
        RunConfig::fixed(ga, 2e-3),
        RunConfig::fixed(Integrator::Rk4, 1e-3),
        RunConfig::controlled(Integrator::DormandPrince, 1e-6),
        RunConfig::controlled(ga, 1e-4),
    ];
    let bench = |jobs, dir: &PathBuf| {
        let s = WorkPrecisionSettings {
            reference_dt: 1e-4,
            reference_integrator: Integrator::DormandPrince,
            duration: 0.5,
            sample: 0.01,
            repeats: 1,
            jobs,
        };
        work_precision(&model, &configs, s, dir).unwrap()
    };
    let (x, y) = (bench(1, &serial), bench(2, &parallel));
    for (p, q) in x.iter().zip(&y) {
        assert_eq!((p.error, p.steps, p.rejected), (q.error, q.steps, q.rejected), "{}", p.integrator);
    }
    assert_eq!(
        without(&read(&serial, "work_precision.csv"), &["median_wall_time_s"]),
        without(&read(&parallel, "work_precision.csv"), &["median_wall_time_s"])
    );
    std::fs::remove_dir_all(&serial).ok();
    std::fs::remove_dir_all(&parallel).ok();
}

#[test]
fn the_friction_study_shows_where_a_deployment_stalls() {
    let out = scratch("friction_study");
    let model = common::bundled("prism3.toml");
    let result =
        tensegrity::study::friction_study(&model, &[0.0, 0.05, 0.3, 1.0], Some("bar0_1.b"), &out).unwrap();
    assert_eq!(result.cable, "ring");
    let [free, low, held, stuck] = &result.rows[..] else { panic!("{result:?}") };
    // without friction one tension along the ring, and nothing to slip against
    assert!(free.route_tension.windows(2).all(|w| (w[0] - w[1]).abs() < 1e-6 * w[0]), "{free:?}");
    assert!(low.largest_slip > 0.01, "at mu 0.05 rope runs over the pulleys: {low:?}");
    assert_eq!(held.largest_slip, 0.0, "at mu 0.3 the pulleys hold all the way: {held:?}");
    // the wound segment carries the most, and more friction than holding changes nothing
    assert!(held.route_tension[0] > held.route_tension[1] && held.route_tension[0] > held.route_tension[2]);
    assert!((held.final_displacement - stuck.final_displacement).abs() < 1e-9);
    assert!((held.final_displacement - free.final_displacement).abs() > 0.01);
    for f in [
        "friction_path.csv",
        "friction_route_tension.csv",
        "friction_route_tension.png",
        "friction_route_tension.svg",
        "friction_deployment.png",
    ] {
        assert!(std::fs::metadata(out.join(f)).map(|m| m.len() > 0).unwrap_or(false), "{f} written");
    }
    let csv = std::fs::read_to_string(out.join("friction_route_tension.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 4 * 3, "a row per coefficient and segment:\n{csv}");
    assert!(result.markdown().contains("| 0.3 |"));
    // careless input
    assert!(tensegrity::study::friction_study(&model, &[-0.1], None, &out).is_err());
    assert!(tensegrity::study::friction_study(&model, &[f64::NAN], None, &out).is_err());
    let atwood = common::bundled("atwood.toml");
    assert!(tensegrity::study::friction_study(&atwood, &[0.1], None, &out).unwrap_err().contains("schedule"));
}

#[test]
fn the_six_bar_study_converges_to_its_quasi_static_path_up_to_the_tip() {
    // the six-bar's haul tips it over: its quasi-static path, its feet held by stick-slip
    // friction from load step to load step, ends at the limit point, before the schedule does.
    // The study compares the runs up to that fraction of their schedules, each starting at rest
    // in the path's first equilibrium, and the displacement deviation falls below 1 % as the
    // actuation slows (the scene's own actuation time is 2.2 s)
    let model = common::bundled("sixbar");
    let out = scratch("study-sixbar");
    let settings = tensegrity::sim::SimSettings::default();
    let times = [2.2, 4.4, 22.0];
    let r = tensegrity::study::deployment_study(&model, &times, None, settings, 0.5, 0, &out).unwrap();
    let end = r.path_end.as_ref().expect("the path ends before the schedule");
    assert!(end.fraction > 0.75 && end.fraction < 0.9, "ends at {}", end.fraction);
    // where the foot y0.b lifts: the summary names it and says the robot tips there
    assert!(end.reason.contains("`y0.b@floor` carries") && end.reason.contains("tips"), "{}", end.reason);
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(
        summary.contains(&format!(
            "The quasi-static path ends at {:.1} % of the schedule",
            100.0 * end.fraction
        )),
        "{summary}"
    );
    // held along the whole compared path: no load step before the end set its feet down afresh
    if let Some(t) = r.contacts_released {
        assert!(t >= end.fraction * model.schedule.end_time(), "released at {t} s:\n{summary}");
        assert!(summary.contains("s on, the quasi-static path could not hold its contacts"), "{summary}");
    }
    let deviations: Vec<f64> = r.rows.iter().map(|row| row.displacement_deviation.abs()).collect();
    assert!(deviations.windows(2).all(|w| w[1] < w[0]), "deviations {deviations:?}\n{summary}");
    assert!(deviations[2] < 0.01, "at T = 22 s: {}\n{summary}", deviations[2]);
    for row in &r.rows {
        assert!(row.tension_deviation.abs() < 0.01, "T = {}: {}", row.ramp_time, row.tension_deviation);
    }
    for t in times {
        let csv = std::fs::read_to_string(out.join(format!("dynamic_T{t}.csv"))).unwrap();
        // the runs stop where the path ends: their last row is at that fraction of their
        // schedule (time-scaled to end at T)
        let last: f64 = csv.lines().last().unwrap().split(',').next().unwrap().parse().unwrap();
        assert!((last - end.fraction * t).abs() <= 1.5e-3, "T = {t}: last row at {last} s");
    }
    // every run starts where the path does: its first tensions are the path's first
    let first = |file: &str, column: usize| -> f64 {
        let text = std::fs::read_to_string(out.join(file)).unwrap();
        text.lines().nth(1).unwrap().split(',').nth(column).unwrap().parse().unwrap()
    };
    let qs_header = std::fs::read_to_string(out.join("quasi_static.csv")).unwrap();
    let qs_c00 = qs_header.lines().next().unwrap().split(',').position(|c| c == "c00_tension_N").unwrap();
    let (path_c00, run_c00) = (first("quasi_static.csv", qs_c00), first("dynamic_T22.csv", 1));
    assert!((path_c00 - run_c00).abs() < 1e-3 * path_c00, "path {path_c00} N, run {run_c00} N");
    // both plots show the path and the runs
    let histories = std::fs::read_to_string(out.join("histories.svg")).unwrap();
    assert!(histories.contains("quasi-static") && histories.contains("T = 22 s"));
    assert!(out.join("deviation.svg").exists());
}

#[test]
fn a_prism_standing_on_a_floor_deploys_dynamically_as_its_held_quasi_static_path_when_slow() {
    // config/examples/prism_on_floor.toml (docs/accuracy.md): a free prism on three feet with
    // stick-slip friction, its top ring pulled in. The quasi-static path holds the feet from load
    // step to load step; the dynamic runs, each from the path's first equilibrium, approach it as
    // the actuation slows (a feet-sliding path used to be 86 % off whatever the actuation time)
    let model = tensegrity::scene::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/examples/prism_on_floor.toml"),
    )
    .unwrap();
    let out = scratch("study-prism-on-floor");
    let settings = tensegrity::sim::SimSettings::default();
    let r =
        tensegrity::study::deployment_study(&model, &[1.0, 5.0, 20.0], None, settings, 1.0, 0, &out).unwrap();
    assert!(r.path_end.is_none() && r.contacts_released.is_none(), "{}", r.markdown());
    let deviations: Vec<f64> = r.rows.iter().map(|row| row.displacement_deviation.abs()).collect();
    assert!(deviations.windows(2).all(|w| w[1] < w[0]), "{}", r.markdown());
    assert!(deviations[2] < 0.01 && r.rows[2].tension_deviation.abs() < 0.01, "{}", r.markdown());
    // the twist drags the feet: along the path the three carry the weight and slip at their
    // cone (friction mu N) from the first load step on; the slowest run's feet slide as far
    let table = |file: &str| -> Vec<std::collections::HashMap<String, f64>> {
        let text = std::fs::read_to_string(out.join(file)).unwrap();
        let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
        let rows = text.lines().skip(1).map(|line| {
            header
                .iter()
                .zip(line.split(','))
                .filter_map(|(h, v)| Some((h.to_string(), v.parse().ok()?)))
                .collect()
        });
        rows.collect()
    };
    let path = table("quasi_static.csv");
    assert_eq!(path.len(), 41, "a row per load step");
    let weight = 3.0 * 2.0 * 9.81;
    for row in &path[1..] {
        let normal: f64 = (0..3).map(|i| row[&format!("bar{i}.a@floor_normal_force_N")]).sum();
        assert!((normal - weight).abs() < 1e-9 * weight, "the feet carry {normal} N");
        for i in 0..3 {
            let (f, n) =
                (row[&format!("bar{i}.a@floor_friction_N")], row[&format!("bar{i}.a@floor_normal_force_N")]);
            assert!((f - 0.8 * n).abs() < 1e-9 * n, "bar{i}.a: friction {f} N, mu N {} N", 0.8 * n);
        }
    }
    let slide = |rows: &[std::collections::HashMap<String, f64>], i: usize| {
        let (a, b) = (&rows[0], &rows[rows.len() - 1]);
        let d = |axis: &str| b[&format!("bar{i}.a_{axis}_m")] - a[&format!("bar{i}.a_{axis}_m")];
        d("x").hypot(d("y"))
    };
    let slowest = table("dynamic_T20.csv");
    for i in 0..3 {
        let (quasi, dynamic) = (slide(&path, i), slide(&slowest, i));
        assert!(quasi > 0.02, "bar{i}.a slides {quasi} m");
        assert!(
            (dynamic - quasi).abs() < 5e-3 * quasi,
            "bar{i}.a slides {quasi} m on the path, {dynamic} m at T = 20 s"
        );
    }
}
