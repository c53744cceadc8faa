//! The browser viewer (`tensegrity view`), tested as a user meets it:
//! - in a real browser (Debian's headless Chromium): a recorded six-bar roll and a live node show
//!   six struts and 24 cables in the page's own scene graph, the struts' colour where the
//!   structure stands, a picture that changes while playing, and no error in the browser's
//!   console; a node killed mid-view is said to have stopped, on the page and the terminal;
//! - careless input: a missing file, a damaged bag, a bag of another scene, no node, a port in
//!   use, a node without its scene: a message naming what is wrong and a non-zero exit;
//! - the page's data: the mode animation's frames, and no NaN ever sent (a null instead).
//!
//! The browser tests need `/usr/bin/chromium` (`.ci/test` installs it and sets
//! `TENSEGRITY_REQUIRE_BROWSER=1`, so CI fails without it); elsewhere they say they are skipped.
//! The README's screenshot is the one the recorded-roll test takes (`docs/img/viewer-sixbar.png`).

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

const VIEW: &str = env!("CARGO_BIN_EXE_tensegrity");

/// The browser, or None (and why) when this machine has none and none is required.
fn chromium() -> Option<PathBuf> {
    let path =
        PathBuf::from(std::env::var("TENSEGRITY_CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into()));
    if path.exists() {
        return Some(path);
    }
    assert!(
        std::env::var_os("TENSEGRITY_REQUIRE_BROWSER").is_none(),
        "{} is missing and TENSEGRITY_REQUIRE_BROWSER is set (.ci/test installs Debian's chromium)",
        path.display()
    );
    eprintln!("skipped: no browser at {} (apt-get install chromium)", path.display());
    None
}

/// A running `tensegrity view`, its address, and its standard error lines as they come.
struct Viewer {
    child: Child,
    url: String,
    #[cfg_attr(not(feature = "shm"), allow(dead_code))]
    stderr: mpsc::Receiver<String>,
}

impl Viewer {
    fn start(args: &[&str]) -> Viewer {
        let mut cmd = Command::new(VIEW);
        tensegrity::testing::die_with_parent(&mut cmd);
        let mut child = cmd
            .arg("view")
            .args(args)
            .args(["--port", "0"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let (tx, stderr) = mpsc::channel();
        let err = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(err).lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let mut url = None;
        let mut line = String::new();
        while out.read_line(&mut line).unwrap_or(0) > 0 {
            if let Some(at) = line.find("http://127.0.0.1:") {
                url = Some(line[at..].split_whitespace().next().unwrap().to_string());
                break;
            }
            line.clear();
        }
        let url = url.unwrap_or_else(|| {
            let status = child.wait().unwrap();
            let said: Vec<String> = stderr.try_iter().collect();
            panic!("the viewer printed no address ({status}): {}", said.join("\n"))
        });
        std::thread::spawn(move || std::io::copy(&mut out, &mut std::io::sink()));
        Viewer { child, url, stderr }
    }

    /// Waits up to `timeout` for a standard-error line containing `text`.
    #[cfg_attr(not(feature = "shm"), allow(dead_code))]
    fn said(&self, text: &str, timeout: Duration) -> Option<String> {
        let end = Instant::now() + timeout;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            match self.stderr.recv_timeout(left) {
                Ok(line) if line.contains(text) => return Some(line),
                Ok(_) => {}
                Err(_) => return None,
            }
        }
        None
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// What a browser run gave: the page's DOM or a screenshot, and the browser's console lines.
struct Browsed {
    dom: String,
    console: Vec<String>,
}

/// Loads `url` in headless Chromium for `budget_ms` of (virtual) time, then dumps the DOM or, with
/// `screenshot`, writes a 1000 x 640 PNG there.
fn browse(browser: &Path, url: &str, budget_ms: u32, screenshot: Option<&Path>) -> Browsed {
    let profile = common::scratch(&format!("chromium-{}", url.len() + budget_ms as usize));
    let profile = profile.join(format!("p{}", Instant::now().elapsed().as_nanos() ^ u128::from(budget_ms)));
    let mut cmd = Command::new(browser);
    tensegrity::testing::die_with_parent(&mut cmd);
    cmd.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--enable-logging=stderr",
        "--v=0",
        "--window-size=1000,640",
    ])
    .arg(format!("--user-data-dir={}", profile.display()))
    .arg(format!("--virtual-time-budget={budget_ms}"));
    match screenshot {
        Some(p) => cmd.arg(format!("--screenshot={}", p.display())),
        None => cmd.arg("--dump-dom"),
    };
    let out = cmd.arg(url).stdin(Stdio::null()).output().unwrap();
    assert!(out.status.success(), "chromium failed: {}", String::from_utf8_lossy(&out.stderr));
    let console = String::from_utf8_lossy(&out.stderr)
        .lines()
        .filter(|l| l.contains(":CONSOLE") || l.contains("Uncaught"))
        .map(String::from)
        .collect();
    Browsed { dom: String::from_utf8_lossy(&out.stdout).into_owned(), console }
}

/// The `data-NAME` attribute of the page's scene-graph element.
fn graph(dom: &str, name: &str) -> String {
    let at = dom.find("id=\"scene-graph\"").unwrap_or_else(|| panic!("no scene graph in the page:\n{dom}"));
    let element = &dom[dom[..at].rfind('<').unwrap()..];
    let element = &element[..element.find('>').unwrap()];
    let key = format!("data-{name}=\"");
    let start = element.find(&key).unwrap_or_else(|| panic!("no {key} in {element}")) + key.len();
    element[start..start + element[start..].find('"').unwrap()].to_string()
}

/// RGB pixels of a PNG.
fn pixels(path: &Path) -> (usize, usize, Vec<[u8; 3]>) {
    let decoder = png::Decoder::new(std::fs::File::open(path).unwrap());
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    let channels = info.color_type.samples();
    let px = buf[..info.buffer_size()].chunks(channels).map(|c| [c[0], c[1], c[2]]).collect();
    (info.width as usize, info.height as usize, px)
}

/// Pixels of the struts' blue-grey (`STRUT` in viewer.js, shaded) in the middle of the drawing
/// area (the left 700 of 1000 pixels; the panel is on the right).
fn strut_pixels(path: &Path) -> usize {
    let (w, h, px) = pixels(path);
    assert_eq!((w, h), (1000, 640));
    let mut n = 0;
    for y in h / 6..h * 5 / 6 {
        for x in 700 / 6..700 * 5 / 6 {
            let [r, g, b] = px[y * w + x].map(i32::from);
            if b.max(g).max(r) < 150 && b >= r + 10 && g >= r && g <= b && b - r < 45 {
                n += 1;
            }
        }
    }
    n
}

/// Share of pixels that differ between two screenshots.
fn changed(a: &Path, b: &Path) -> f64 {
    let (_, _, pa) = pixels(a);
    let (_, _, pb) = pixels(b);
    pa.iter().zip(&pb).filter(|(x, y)| x != y).count() as f64 / pa.len() as f64
}

fn assert_no_console_errors(b: &Browsed, what: &str) {
    assert!(b.console.is_empty(), "{what}: the browser's console says:\n{}", b.console.join("\n"));
}

/// A recorded roll of the six-bar (its scene's haul), as a user records one.
fn six_bar_bag(dir: &Path) -> PathBuf {
    let bag = dir.join("roll");
    let out = Command::new(VIEW)
        .args(["deploy", "config/scenes/sixbar.toml", "--dynamic", "--duration", "3"])
        .arg("--out")
        .arg(dir.join("roll.csv"))
        .arg("--record")
        .arg(&bag)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    bag
}

#[test]
fn a_recorded_six_bar_roll_plays_in_a_browser() {
    let Some(browser) = chromium() else { return };
    let dir = common::scratch("viewer-bag");
    let bag = six_bar_bag(&dir);
    let viewer = Viewer::start(&[bag.to_str().unwrap(), "--serve-for", "300"]);

    let still = browse(&browser, &format!("{}?frame=0", viewer.url), 1500, None);
    assert_no_console_errors(&still, "the bag at its first frame");
    assert_eq!(graph(&still.dom, "struts"), "6");
    assert_eq!(graph(&still.dom, "cables"), "24");
    assert_eq!(graph(&still.dom, "bodies"), "6");
    assert_eq!(graph(&still.dom, "state"), "recorded");
    assert_eq!(graph(&still.dom, "errors"), "0");
    let frames: usize = graph(&still.dom, "frames").parse().unwrap();
    assert!((170..=185).contains(&frames), "3 s at 60 frames a second: {frames} frames");
    assert_eq!(graph(&still.dom, "frame-index"), "0");

    // played (the default) for 2 s of the browser's time, at 1x: about 2 s of the roll on
    let played = browse(&browser, &viewer.url, 2000, None);
    assert_no_console_errors(&played, "the bag playing");
    let t: f64 = graph(&played.dom, "time").parse().unwrap();
    assert!(t > 1.0 && t <= 3.0, "after 2 s of playing the page shows t = {t}");
    assert!(graph(&played.dom, "draws").parse::<u32>().unwrap() > 10);

    // pictures: the struts where the structure stands, and the picture changes as it plays
    let first = dir.join("first.png");
    let later = dir.join("later.png");
    assert_no_console_errors(
        &browse(&browser, &format!("{}?frame=0", viewer.url), 1500, Some(&first)),
        "screenshot",
    );
    assert_no_console_errors(&browse(&browser, &viewer.url, 2500, Some(&later)), "screenshot");
    for shot in [&first, &later] {
        let n = strut_pixels(shot);
        assert!(n > 1500, "{}: {n} pixels of the struts' colour in the middle of the view", shot.display());
    }
    let moved = changed(&first, &later);
    assert!(moved > 0.01, "playing changed {:.2} % of the picture", 100.0 * moved);

    // the README's screenshot: the roll under way, its contacts pressing
    let readme_shot = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/img/viewer-sixbar.png");
    std::fs::create_dir_all(readme_shot.parent().unwrap()).unwrap();
    browse(&browser, &format!("{}?frame=120&cable=c05", viewer.url), 1500, Some(&readme_shot));
    assert!(strut_pixels(&readme_shot) > 1500);
}

/// A `tensegrity_node` serving shared memory only under `prefix`, rolling the six-bar by its
/// schedule in real time.
#[cfg(feature = "shm")]
fn rolling_node(prefix: &str) -> Child {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_tensegrity_node"));
    tensegrity::testing::die_with_parent(&mut cmd);
    cmd.args(["config/scenes/sixbar.toml", "--ros-args", "-p", "transports:=shm", "-p"])
        .arg(format!("shm_prefix:={prefix}"))
        .args(["-p", "follow_schedule:=true"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

#[test]
#[cfg(feature = "shm")]
fn a_live_node_is_followed_in_a_browser_and_its_stop_is_said() {
    let Some(browser) = chromium() else { return };
    let dir = common::scratch("viewer-live");
    let prefix = format!("viewer_live_{}", std::process::id());
    let mut node = rolling_node(&prefix);
    let viewer = Viewer::start(&[
        &format!("node:{prefix}"),
        "--scene",
        "config/scenes/sixbar.toml",
        "--timeout",
        "20",
        "--serve-for",
        "300",
    ]);
    let page = browse(&browser, &viewer.url, 1500, None);
    assert_no_console_errors(&page, "the live node");
    assert_eq!(graph(&page.dom, "struts"), "6");
    assert_eq!(graph(&page.dom, "cables"), "24");
    assert_eq!(graph(&page.dom, "state"), "playing");
    assert!(graph(&page.dom, "frames").parse::<usize>().unwrap() > 0);

    let a = dir.join("a.png");
    let b = dir.join("b.png");
    browse(&browser, &viewer.url, 800, Some(&a));
    std::thread::sleep(Duration::from_millis(1200));
    browse(&browser, &viewer.url, 800, Some(&b));
    assert!(strut_pixels(&a) > 1500 && strut_pixels(&b) > 1500);
    assert!(changed(&a, &b) > 0.002, "the live picture did not change as the node rolled on");

    // a viewer frozen (SIGSTOP) and then killed holds nothing up: the node goes on stepping,
    // as the first viewer sees
    let frozen = Viewer::start(&[
        &format!("node:{prefix}"),
        "--scene",
        "config/scenes/sixbar.toml",
        "--serve-for",
        "300",
    ]);
    let newest_step = |url: &str| -> u64 {
        let next = serde_json::from_str::<serde_json::Value>(&get(url, "/frames?max=1")).unwrap()["next"]
            .as_u64()
            .unwrap();
        let d: serde_json::Value =
            serde_json::from_str(&get(url, &format!("/frames?from={}", next - 1))).unwrap();
        d["frames"][0]["step"].as_u64().unwrap()
    };
    let signal = |sig: &str, pid: u32| {
        assert!(Command::new("kill").args([sig, &pid.to_string()]).status().unwrap().success())
    };
    signal("-STOP", frozen.child.id());
    let before = newest_step(&viewer.url);
    std::thread::sleep(Duration::from_millis(1500));
    let after = newest_step(&viewer.url);
    assert!(
        after >= before + 500,
        "with a frozen viewer the node went from step {before} to {after} in 1.5 s"
    );
    drop(frozen);
    std::thread::sleep(Duration::from_millis(500));
    assert!(node.try_wait().unwrap().is_none(), "the node stopped with a viewer");
    assert!(newest_step(&viewer.url) > after);

    // killed without a word: the viewer says so on its terminal and on the page, and goes on
    // serving what it has
    node.kill().unwrap();
    node.wait().unwrap();
    let line =
        viewer.said("stopped", Duration::from_secs(20)).expect("the viewer never said the node stopped");
    assert!(line.contains(&prefix), "{line}");
    let page = browse(&browser, &viewer.url, 800, None);
    assert_no_console_errors(&page, "after the node stopped");
    assert_eq!(graph(&page.dom, "state"), "stopped");
    assert!(graph(&page.dom, "frames").parse::<usize>().unwrap() > 0);
}

/// Runs `tensegrity view ARGS --port 0 --serve-for 0`: its exit success and standard error.
fn view_fails(args: &[&str]) -> String {
    let out = Command::new(VIEW)
        .arg("view")
        .args(args)
        .args(["--serve-for", "0"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(!out.status.success(), "view {args:?} succeeded");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn careless_targets_get_a_message_and_a_failing_exit() {
    let dir = common::scratch("viewer-careless");
    let err = view_fails(&["no/such/scene.toml", "--port", "0"]);
    assert!(err.contains("no/such/scene.toml") && err.contains("no such file"), "{err}");
    let err = view_fails(&["sixbarr", "--port", "0"]);
    assert!(err.contains("bundled: "), "{err}");

    // a bag of the six-bar, then damaged copies of it
    let bag = six_bar_bag(&dir);
    let mcap = std::fs::read_dir(&bag)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "mcap"))
        .unwrap();
    let bytes = std::fs::read(&mcap).unwrap();
    let garbage = dir.join("garbage.mcap");
    std::fs::write(&garbage, b"this is not an MCAP file at all, only text").unwrap();
    let err = view_fails(&[garbage.to_str().unwrap(), "--port", "0"]);
    assert!(err.contains("garbage.mcap"), "{err}");
    let empty = dir.join("empty_dir");
    std::fs::create_dir_all(&empty).unwrap();
    let err = view_fails(&[empty.to_str().unwrap(), "--port", "0"]);
    assert!(err.contains("empty_dir"), "{err}");

    // cut in the middle: what can be read is shown, and the terminal says it is cut
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let mut viewer = Command::new(VIEW)
        .args(["view", cut.to_str().unwrap(), "--port", "0", "--serve-for", "0"])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&viewer.stderr).into_owned();
    assert!(viewer.status.success(), "{said}");
    assert!(said.contains("cut short"), "{said}");
    viewer.stdout.clear();

    // the bag checked against a scene the user names
    let err = view_fails(&[bag.to_str().unwrap(), "--scene", "config/scenes/prism3.toml", "--port", "0"]);
    assert!(err.contains("records scene 'sixbar'") && err.contains("prism3"), "{err}");

    // no node there; a node without its scene
    let err = view_fails(&[
        "node:nobody_is_here",
        "--scene",
        "config/scenes/sixbar.toml",
        "--timeout",
        "0.3",
        "--port",
        "0",
    ]);
    let why = if cfg!(feature = "shm") { "no node" } else { "without shared memory" };
    assert!(err.contains("nobody_is_here") && err.contains(why), "{err}");
    let err = view_fails(&["node:nobody_is_here", "--port", "0"]);
    assert!(err.contains(if cfg!(feature = "shm") { "--scene" } else { "without shared memory" }), "{err}");

    // a port in use
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port().to_string();
    let err = view_fails(&["prism3", "--port", &port]);
    assert!(err.contains(&port) && err.contains("in use"), "{err}");

    // nonsense numbers
    let err = view_fails(&["prism3", "--port", "0", "--fps", "nan"]);
    assert!(err.contains("--fps"), "{err}");
}

/// GET `path` from the viewer at `url`: the body.
fn get(url: &str, path: &str) -> String {
    let addr = url.trim_start_matches("http://").trim_end_matches('/');
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    write!(s, "GET {path} HTTP/1.0\r\nHost: {addr}\r\n\r\n").unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).unwrap();
    let (head, body) = out.split_once("\r\n\r\n").unwrap();
    assert!(head.contains(" 200 "), "{path}: {head}");
    body.to_string()
}

#[test]
fn the_modes_animate_and_no_nan_reaches_the_page() {
    let viewer = Viewer::start(&["prism3", "--modes", "2", "--serve-for", "60"]);
    let scene: serde_json::Value = serde_json::from_str(&get(&viewer.url, "/scene.json")).unwrap();
    assert_eq!(scene["source"], "modes");
    assert_eq!(scene["struts"].as_array().unwrap().len(), 3);
    let frames: serde_json::Value = serde_json::from_str(&get(&viewer.url, "/frames?from=0")).unwrap();
    let list = frames["frames"].as_array().unwrap();
    assert_eq!(list.len(), 2 * 48, "two modes of 48 frames");
    assert!(frames["status"]["message"].as_str().unwrap().contains("mode 2: "));
    // the mode moves the vertices and stays finite
    let v = |k: usize| -> Vec<f64> {
        list[k]["v"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
    };
    assert!(v(0).iter().zip(v(12)).any(|(a, b)| (a - b).abs() > 1e-3));
    // later frames only, as a live page asks
    let tail: serde_json::Value = serde_json::from_str(&get(&viewer.url, "/frames?from=90&max=3")).unwrap();
    assert_eq!(tail["frames"].as_array().unwrap().len(), 3);
    assert_eq!(tail["frames"][0]["seq"], 90);
    let page = get(&viewer.url, "/");
    assert!(page.contains("viewer.js") && !page.contains("http://") && !page.contains("https://"));

    // a state gone bad is drawn as gaps: a NaN becomes null, and the JSON still parses
    use tensegrity::io::view::{Frame, FrameStore, ViewServer, ViewStatus};
    let store =
        std::sync::Arc::new(FrameStore::new(4, ViewStatus { state: "still".into(), message: String::new() }));
    store.push(&Frame {
        time: 0.0,
        vertices: vec![[f64::NAN, 0.0, 1.0]],
        tension: vec![f64::INFINITY],
        rest_length: vec![1.0],
        slack: vec![false],
        ..Frame::default()
    });
    let server = ViewServer::bind(0, "{}".into(), store).unwrap();
    let url = server.url();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let serving = {
        let stop = stop.clone();
        std::thread::spawn(move || server.serve_until(&stop))
    };
    let body = get(&url, "/frames");
    let parsed: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert!(parsed["frames"][0]["v"][0].is_null() && parsed["frames"][0]["T"][0].is_null(), "{body}");
    assert!(!body.contains("NaN") && !body.contains("inf"));
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    serving.join().unwrap();
}
