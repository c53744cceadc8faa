// tensegrity view: draws the scene of /scene.json with the frames of /frames (served by
// `tensegrity view`) on a 2-D canvas, in perspective, with an orbit camera. No library, nothing
// fetched from outside 127.0.0.1.
"use strict";

(function () {
  const $ = (id) => document.getElementById(id);
  const errors = [];
  function reportError(text) {
    errors.push(String(text));
    $("errors").textContent = errors.join("\n");
    publishGraph();
  }
  window.addEventListener("error", (e) => reportError(e.message || e));
  window.addEventListener("unhandledrejection", (e) => reportError(e.reason || "unhandled rejection"));

  const params = new URLSearchParams(location.search);
  const canvas = $("canvas");
  const ctx = canvas.getContext("2d");

  // ---- state ------------------------------------------------------------------------------
  let scene = null;          // /scene.json
  let frames = [];           // frames held, in seq order
  let firstSeq = 0;          // seq of frames[0]
  let nextSeq = 0;           // seq to ask for next
  let status = { state: "loading", message: "" };
  let largestTension = 0, largestForce = 0;
  let index = 0;             // shown frame (index into frames)
  let playing = false;
  let following = false;     // live: show the newest frame
  let playhead = 0;          // simulated time being shown (replay)
  let speed = Number(params.get("speed") || 1);
  let lastTick = null;
  let connected = true;
  let drawCount = 0;
  let drawMs = 0;            // a draw's wall time, ms (moving average)

  // camera: orbit about `target`, `up` the scene's (against gravity)
  const cam = { az: -0.9, el: 0.28, dist: 3, target: [0, 0, 0], fov: 45 * Math.PI / 180 };
  let basis = null; // {u, e1, e2}

  // ---- small vector helpers ----------------------------------------------------------------
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
  const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = (a) => Math.sqrt(dot(a, a));
  const unit = (a) => { const n = norm(a); return n > 0 ? mul(a, 1 / n) : [0, 0, 1]; };

  function makeBasis(up) {
    const u = unit(up);
    // horizontal axes: world x (or y) with its part along up removed
    let e1 = sub([1, 0, 0], mul(u, u[0]));
    if (norm(e1) < 1e-6) e1 = sub([0, 1, 0], mul(u, u[1]));
    e1 = unit(e1);
    return { u, e1, e2: cross(u, e1) };
  }

  function resetView() {
    if (!scene) return;
    cam.target = scene.centre.slice();
    cam.dist = Math.max(scene.size, 1e-3) * 0.62 / Math.sin(cam.fov / 2);
    cam.az = -0.9;
    cam.el = 0.28;
  }

  // ---- camera and projection ---------------------------------------------------------------
  let view = null;
  function updateView(w, h) {
    const { u, e1, e2 } = basis;
    const ce = Math.cos(cam.el), se = Math.sin(cam.el);
    const dir = add(add(mul(e1, ce * Math.cos(cam.az)), mul(e2, ce * Math.sin(cam.az))), mul(u, se));
    const eye = add(cam.target, mul(dir, cam.dist));
    const f = mul(dir, -1);
    const r = unit(cross(f, u));
    const up = cross(r, f);
    const focal = 0.5 * h / Math.tan(cam.fov / 2);
    view = { eye, f, r, up, focal, cx: 0.5 * w, cy: 0.5 * h, near: cam.dist * 1e-3 };
  }
  function project(p) {
    const d = [p[0] - view.eye[0], p[1] - view.eye[1], p[2] - view.eye[2]];
    const z = dot(d, view.f);
    if (!(z > view.near)) return null;
    return [view.cx + view.focal * dot(d, view.r) / z, view.cy - view.focal * dot(d, view.up) / z, z];
  }

  // ---- colours -----------------------------------------------------------------------------
  const STOPS = [[0.0, [49, 54, 149]], [0.25, [69, 117, 180]], [0.5, [116, 173, 109]], [0.75, [244, 165, 40]], [1.0, [200, 30, 30]]];
  function tensionColor(x) {
    x = Math.min(1, Math.max(0, x || 0));
    for (let i = 1; i < STOPS.length; i++) {
      if (x <= STOPS[i][0]) {
        const [x0, c0] = STOPS[i - 1], [x1, c1] = STOPS[i];
        const s = (x - x0) / (x1 - x0);
        return `rgb(${Math.round(c0[0] + s * (c1[0] - c0[0]))},${Math.round(c0[1] + s * (c1[1] - c0[1]))},${Math.round(c0[2] + s * (c1[2] - c0[2]))})`;
      }
    }
    return "rgb(200,30,30)";
  }
  const STRUT = [92, 104, 120];

  // ---- drawing -----------------------------------------------------------------------------
  function vertex(frame, i) {
    const v = frame.v;
    return [v[3 * i], v[3 * i + 1], v[3 * i + 2]];
  }
  function finite(p) { return p[0] !== null && p[1] !== null && p[2] !== null && isFinite(p[0]) && isFinite(p[1]) && isFinite(p[2]); }

  function drawGround(w, h) {
    for (const g of scene.grounds) {
      const n = unit(g.normal);
      // the plane around the structure's centre, projected onto it
      const c = sub(scene.centre, mul(n, dot(scene.centre, n) - g.offset));
      let a = sub([1, 0, 0], mul(n, n[0]));
      if (norm(a) < 1e-6) a = sub([0, 1, 0], mul(n, n[1]));
      a = unit(a);
      const b = cross(n, a);
      const half = 1.1 * scene.size;
      const cells = 12, step = 2 * half / cells;
      const corner = (s, t) => add(c, add(mul(a, s), mul(b, t)));
      const quad = [corner(-half, -half), corner(half, -half), corner(half, half), corner(-half, half)].map(project);
      if (quad.every((q) => q)) {
        ctx.fillStyle = "rgba(206, 196, 176, 0.55)";
        ctx.beginPath();
        quad.forEach((q, k) => (k ? ctx.lineTo(q[0], q[1]) : ctx.moveTo(q[0], q[1])));
        ctx.closePath();
        ctx.fill();
      }
      ctx.strokeStyle = "rgba(120, 110, 95, 0.45)";
      ctx.lineWidth = 1;
      ctx.beginPath();
      for (let k = 0; k <= cells; k++) {
        const s = -half + k * step;
        for (const [p, q] of [[corner(s, -half), corner(s, half)], [corner(-half, s), corner(half, s)]]) {
          const P = project(p), Q = project(q);
          if (P && Q) { ctx.moveTo(P[0], P[1]); ctx.lineTo(Q[0], Q[1]); }
        }
      }
      ctx.stroke();
    }
  }

  function draw() {
    const began = performance.now();
    drawScene();
    const took = performance.now() - began;
    drawMs = drawCount > 1 ? 0.9 * drawMs + 0.1 * took : took;
  }

  function drawScene() {
    const dpr = window.devicePixelRatio || 1;
    const w = canvas.clientWidth, h = canvas.clientHeight;
    if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
      canvas.width = Math.round(w * dpr);
      canvas.height = Math.round(h * dpr);
    }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    if (!scene) return;
    updateView(w, h);
    drawGround(w, h);
    const frame = frames[index];
    if (!frame || !frame.v || frame.v.length < 3 * scene.vertex_count) return;
    const items = [];
    const tmax = largestTension > 0 ? largestTension : 1;
    // cables, segment by segment
    scene.cables.forEach((c, ci) => {
      const t = frame.T[ci];
      const slack = frame.slack[ci] === 1;
      for (let k = 0; k + 1 < c.route.length; k++) {
        const p = vertex(frame, c.route[k]), q = vertex(frame, c.route[k + 1]);
        if (!finite(p) || !finite(q)) continue;
        const P = project(p), Q = project(q);
        if (!P || !Q) continue;
        items.push({ z: 0.5 * (P[2] + Q[2]), kind: 0, P, Q, slack: c.tension_only && slack, member: !c.tension_only, x: t / tmax, sel: ci === selected });
      }
    });
    for (const [a, b] of scene.struts) {
      const p = vertex(frame, a), q = vertex(frame, b);
      if (!finite(p) || !finite(q)) continue;
      const P = project(p), Q = project(q);
      if (!P || !Q) continue;
      items.push({ z: 0.5 * (P[2] + Q[2]) + 1e-9, kind: 1, P, Q });
    }
    for (const i of scene.nodes) {
      const p = vertex(frame, i);
      const P = finite(p) && project(p);
      if (P) items.push({ z: P[2], kind: 2, P });
    }
    for (const i of scene.pulleys) {
      const p = vertex(frame, i);
      const P = finite(p) && project(p);
      if (P) items.push({ z: P[2] - 1e-9, kind: 3, P });
    }
    const fscale = largestForce > 0 ? 0.2 * scene.size / largestForce : 0;
    for (let k = 0; k + 5 < frame.c.length + 1; k += 6) {
      const p = frame.c.slice(k, k + 3), f = frame.c.slice(k + 3, k + 6);
      if (!finite(p) || !finite(f)) continue;
      const P = project(p), Q = project(add(p, mul(f, fscale)));
      if (P && Q) items.push({ z: P[2] - 1e-6, kind: 4, P, Q });
    }
    items.sort((a, b) => b.z - a.z);
    const r = scene.strut_radius;
    for (const it of items) {
      if (it.kind === 0) {
        ctx.setLineDash(it.slack ? [5, 4] : []);
        ctx.strokeStyle = it.slack ? "rgb(150,150,150)" : it.member ? "rgb(120,120,120)" : tensionColor(it.x);
        ctx.lineWidth = it.sel ? 3.5 : 1.8;
        ctx.beginPath(); ctx.moveTo(it.P[0], it.P[1]); ctx.lineTo(it.Q[0], it.Q[1]); ctx.stroke();
      } else if (it.kind === 1) {
        ctx.setLineDash([]);
        const width = Math.max(2.5, 2 * r * view.focal / it.z);
        const shade = Math.max(0.55, Math.min(1.15, 1.25 - 0.35 * (it.z - cam.dist + scene.size / 2) / Math.max(scene.size, 1e-6)));
        ctx.lineCap = "round";
        ctx.strokeStyle = `rgb(${Math.round(STRUT[0] * shade)},${Math.round(STRUT[1] * shade)},${Math.round(STRUT[2] * shade)})`;
        ctx.lineWidth = width;
        ctx.beginPath(); ctx.moveTo(it.P[0], it.P[1]); ctx.lineTo(it.Q[0], it.Q[1]); ctx.stroke();
        // a highlight along the rod
        ctx.strokeStyle = "rgba(255,255,255,0.25)";
        ctx.lineWidth = Math.max(1, width * 0.3);
        ctx.beginPath(); ctx.moveTo(it.P[0], it.P[1] - width * 0.18); ctx.lineTo(it.Q[0], it.Q[1] - width * 0.18); ctx.stroke();
        ctx.lineCap = "butt";
      } else if (it.kind === 2) {
        ctx.fillStyle = "rgb(40,46,56)";
        ctx.beginPath(); ctx.arc(it.P[0], it.P[1], Math.max(3, 1.6 * r * view.focal / it.z), 0, 2 * Math.PI); ctx.fill();
      } else if (it.kind === 3) {
        ctx.setLineDash([]);
        ctx.strokeStyle = "rgb(30,30,30)"; ctx.fillStyle = "rgb(235,235,235)"; ctx.lineWidth = 1.2;
        ctx.beginPath(); ctx.arc(it.P[0], it.P[1], 3.2, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
      } else {
        ctx.setLineDash([]);
        arrow(it.P, it.Q);
      }
    }
    ctx.setLineDash([]);
    drawCount++;
  }

  function arrow(P, Q) {
    ctx.strokeStyle = "rgb(214,96,0)"; ctx.fillStyle = "rgb(214,96,0)"; ctx.lineWidth = 2.2;
    ctx.beginPath(); ctx.moveTo(P[0], P[1]); ctx.lineTo(Q[0], Q[1]); ctx.stroke();
    const dx = Q[0] - P[0], dy = Q[1] - P[1], L = Math.hypot(dx, dy);
    if (L > 4) {
      const ux = dx / L, uy = dy / L, s = Math.min(9, 0.4 * L);
      ctx.beginPath(); ctx.moveTo(Q[0], Q[1]);
      ctx.lineTo(Q[0] - s * ux + 0.5 * s * uy, Q[1] - s * uy - 0.5 * s * ux);
      ctx.lineTo(Q[0] - s * ux - 0.5 * s * uy, Q[1] - s * uy + 0.5 * s * ux);
      ctx.closePath(); ctx.fill();
    }
    ctx.beginPath(); ctx.arc(P[0], P[1], 3, 0, 2 * Math.PI); ctx.fill();
  }

  // ---- the side panel ----------------------------------------------------------------------
  let selected = 0;
  function drawColorbar() {
    const c = $("colorbar"), g = c.getContext("2d");
    const w = c.width = c.clientWidth || 270, h = c.height;
    g.clearRect(0, 0, w, h);
    for (let x = 0; x < w; x++) { g.fillStyle = tensionColor(x / (w - 1)); g.fillRect(x, 0, 1, 14); }
    g.fillStyle = "#1d2329"; g.font = "11px system-ui, sans-serif";
    g.textAlign = "left"; g.fillText("0", 0, 28);
    g.textAlign = "right"; g.fillText(fmt(largestTension) + " N", w, 28);
    g.textAlign = "center"; g.fillText(fmt(largestTension / 2), w / 2, 28);
    $("forcescale").textContent = largestForce > 0 && scene
      ? `contact force arrows: ${fmt(0.2 * scene.size * 100)} cm = ${fmt(largestForce)} N`
      : (scene && scene.contacts.length ? "no contact pressing in" : "");
  }
  function fmt(x) {
    if (!isFinite(x)) return "-";
    const a = Math.abs(x);
    if (a === 0) return "0";
    if (a >= 1e4 || a < 1e-3) return x.toExponential(2);
    return Number(x.toPrecision(4)).toString();
  }
  function drawChart() {
    const c = $("chart"), g = c.getContext("2d");
    const w = c.width = c.clientWidth || 270, h = c.height;
    g.clearRect(0, 0, w, h);
    if (!frames.length || !scene || !scene.cables.length) return;
    const L = 34, R = 40, T = 8, B = 18;
    const t0 = frames[0].t, t1 = frames[frames.length - 1].t;
    const span = t1 > t0 ? t1 - t0 : 1;
    const stride = Math.max(1, Math.floor(frames.length / (2 * (w - L - R))));
    let tlo = Infinity, thi = -Infinity, llo = Infinity, lhi = -Infinity;
    for (let k = 0; k < frames.length; k += stride) {
      const f = frames[k], t = f.T[selected], l = f.L0[selected];
      if (isFinite(t) && t !== null) { tlo = Math.min(tlo, t); thi = Math.max(thi, t); }
      if (isFinite(l) && l !== null) { llo = Math.min(llo, l); lhi = Math.max(lhi, l); }
    }
    if (!isFinite(tlo)) { tlo = 0; thi = 1; }
    if (!isFinite(llo)) { llo = 0; lhi = 1; }
    tlo = Math.min(tlo, 0); if (thi - tlo < 1e-12) thi = tlo + 1;
    if (lhi - llo < 1e-9) { llo -= 0.001; lhi += 0.001; }
    const X = (t) => L + (w - L - R) * (t - t0) / span;
    const Y = (v, lo, hi) => T + (h - T - B) * (1 - (v - lo) / (hi - lo));
    g.strokeStyle = "#ccd2d8"; g.lineWidth = 1; g.strokeRect(L, T, w - L - R, h - T - B);
    const line = (get, lo, hi, color, dash) => {
      g.strokeStyle = color; g.setLineDash(dash); g.lineWidth = 1.5; g.beginPath();
      let moved = false;
      for (let k = 0; k < frames.length; k += stride) {
        const v = get(frames[k]);
        if (v === null || !isFinite(v)) { moved = false; continue; }
        const x = X(frames[k].t), y = Y(v, lo, hi);
        if (moved) g.lineTo(x, y); else { g.moveTo(x, y); moved = true; }
      }
      g.stroke(); g.setLineDash([]);
    };
    line((f) => f.L0[selected], llo, lhi, "#4a5560", [4, 3]);
    line((f) => f.T[selected], tlo, thi, "#c0392b", []);
    const f = frames[index];
    if (f) { g.strokeStyle = "#1d2329"; g.beginPath(); g.moveTo(X(f.t), T); g.lineTo(X(f.t), h - B); g.stroke(); }
    g.fillStyle = "#1d2329"; g.font = "10px system-ui, sans-serif";
    g.textAlign = "right"; g.fillText(fmt(thi), L - 3, T + 8); g.fillText(fmt(tlo), L - 3, h - B);
    g.textAlign = "left"; g.fillText(fmt(lhi), w - R + 3, T + 8); g.fillText(fmt(llo), w - R + 3, h - B);
    g.textAlign = "center"; g.fillText(`${fmt(t0)} s`, L + 12, h - 4); g.fillText(`${fmt(t1)} s`, w - R - 12, h - 4);
  }

  function updatePanel() {
    const f = frames[index];
    const state = connected ? status.state : "error";
    const badge = $("state");
    badge.textContent = state;
    badge.className = "badge " + state;
    $("message").textContent = connected ? status.message : "the viewer's server does not answer (was `tensegrity view` stopped?)";
    const banner = $("banner");
    const bad = !connected || ["faulted", "stopped", "error"].includes(state);
    banner.style.display = bad || state === "waiting" ? "block" : "none";
    banner.className = bad ? "" : "warn";
    banner.textContent = !connected ? "viewer server not answering" : status.message || state;
    $("time").textContent = f ? `t = ${f.t.toFixed(3)} s` : "t = -";
    $("frameinfo").textContent = frames.length
      ? `frame ${index + 1} of ${frames.length}${f && f.step ? `, step ${f.step}` : ""}`
      : "no frame yet";
    const slider = $("slider");
    slider.max = Math.max(0, frames.length - 1);
    if (Number(slider.value) !== index) slider.value = index;
    $("play").textContent = (scene && scene.source === "node") ? (following ? "pause view" : "follow") : (playing ? "pause" : "play");
    if (f && scene && scene.cables.length) {
      const c = scene.cables[selected];
      $("cablenow").textContent = `${c.name}: tension ${fmt(f.T[selected])} N, rest length ${fmt(f.L0[selected])} m${f.slack[selected] ? " (slack)" : ""}`;
    }
    drawColorbar();
    drawChart();
    publishGraph();
  }

  // What the page holds, for tests and scripts: the scene graph's counts and the shown frame.
  function publishGraph() {
    const g = $("scene-graph");
    const f = frames[index];
    const d = {
      struts: scene ? scene.struts.length : 0,
      cables: scene ? scene.cables.length : 0,
      bodies: scene ? scene.body_count : 0,
      frames: frames.length,
      frameIndex: index,
      time: f ? f.t : null,
      state: connected ? status.state : "error",
      playing: playing || following,
      draws: drawCount,
      drawMs: drawMs.toFixed(2),
      errors: errors.length,
    };
    for (const [k, v] of Object.entries(d)) g.dataset[k] = String(v);
    window.tensegrityView = d;
  }

  // ---- data --------------------------------------------------------------------------------
  async function fetchJson(url) {
    const r = await fetch(url, { cache: "no-store" });
    if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
    return r.json();
  }

  async function poll() {
    try {
      const d = await fetchJson(`frames?from=${nextSeq}`);
      connected = true;
      status = d.status;
      largestTension = d.largest_tension;
      largestForce = d.largest_force;
      if (d.first > firstSeq) {
        // the server let old frames go (a live node): drop them here too
        const drop = Math.min(frames.length, d.first - firstSeq);
        frames.splice(0, drop);
        index = Math.max(0, index - drop);
        firstSeq = d.first;
      }
      if (d.frames.length) {
        if (!frames.length) firstSeq = d.frames[0].seq;
        for (const f of d.frames) frames.push(f);
        nextSeq = d.frames[d.frames.length - 1].seq + 1;
      }
      if (following && frames.length) index = frames.length - 1;
      const more = nextSeq < d.next;
      setTimeout(poll, more ? 0 : (scene.source === "node" ? 100 : 1000));
    } catch (e) {
      connected = false;
      setTimeout(poll, 1000);
    }
    updatePanel();
  }

  // playback of held frames (a bag or the modes) by simulated time
  function seekTime(t) {
    let lo = 0, hi = frames.length - 1;
    while (lo < hi) {
      const mid = (lo + hi + 1) >> 1;
      if (frames[mid].t <= t) lo = mid; else hi = mid - 1;
    }
    return lo;
  }
  function tick() {
    const now = performance.now();
    if (playing && frames.length > 1 && scene.source !== "node") {
      const dt = lastTick === null ? 0 : (now - lastTick) / 1000;
      playhead += dt * speed;
      const end = frames[frames.length - 1].t;
      if (playhead > end) {
        if (scene.source === "modes") playhead = frames[0].t + ((playhead - frames[0].t) % Math.max(end - frames[0].t, 1e-9));
        else if (status.state === "recorded") { playhead = end; playing = false; }
        else playhead = end;
      }
      index = seekTime(playhead);
    }
    lastTick = now;
    draw();
    updatePanel();
    setTimeout(tick, 33);
  }

  function setIndex(i) {
    index = Math.max(0, Math.min(frames.length - 1, i));
    if (frames[index]) playhead = frames[index].t;
  }

  // ---- input -------------------------------------------------------------------------------
  $("play").onclick = () => {
    if (scene.source === "node") { following = !following; if (following) index = frames.length - 1; return; }
    if (!playing && frames.length && index >= frames.length - 1 && scene.source !== "modes") setIndex(0);
    playing = !playing;
  };
  $("back").onclick = () => { playing = false; following = false; setIndex(index - 1); };
  $("forward").onclick = () => { playing = false; following = false; setIndex(index + 1); };
  $("speed").value = String(speed);
  $("speed").onchange = (e) => { speed = Number(e.target.value) || 1; };
  $("slider").oninput = (e) => { playing = false; following = false; setIndex(Number(e.target.value)); };
  $("cable").onchange = (e) => { selected = Number(e.target.value) || 0; };
  window.addEventListener("keydown", (e) => {
    if (e.key === " ") { $("play").click(); e.preventDefault(); }
    else if (e.key === "ArrowLeft") $("back").click();
    else if (e.key === "ArrowRight") $("forward").click();
  });
  let drag = null;
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("mousedown", (e) => { drag = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 }; canvas.style.cursor = "grabbing"; });
  window.addEventListener("mouseup", () => { drag = null; canvas.style.cursor = "grab"; });
  window.addEventListener("mousemove", (e) => {
    if (!drag || !view) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      const s = cam.dist / view.focal;
      cam.target = add(cam.target, add(mul(view.r, -dx * s), mul(view.up, dy * s)));
    } else {
      cam.az -= dx * 0.008;
      cam.el = Math.max(-1.45, Math.min(1.45, cam.el + dy * 0.008));
    }
  });
  canvas.addEventListener("wheel", (e) => { cam.dist *= Math.exp(0.0012 * e.deltaY); e.preventDefault(); }, { passive: false });
  canvas.addEventListener("dblclick", resetView);

  // ---- start -------------------------------------------------------------------------------
  async function start() {
    try {
      scene = await fetchJson("scene.json");
    } catch (e) {
      connected = false;
      reportError(`cannot load the scene: ${e.message}`);
      updatePanel();
      return;
    }
    basis = makeBasis(scene.up);
    resetView();
    $("title").textContent = scene.name;
    $("label").textContent = `${scene.label} · ${scene.struts.length} struts, ${scene.cables.length} cables`;
    const select = $("cable");
    scene.cables.forEach((c, i) => { const o = document.createElement("option"); o.value = i; o.textContent = c.name; select.appendChild(o); });
    const wanted = params.get("cable");
    const found = scene.cables.findIndex((c) => c.name === wanted);
    if (found >= 0) { selected = found; select.value = String(found); }
    if (scene.source === "node") following = params.get("follow") !== "0";
    else playing = params.get("play") !== "0" && scene.source !== "equilibrium";
    if (params.has("frame")) { playing = false; following = false; }
    await poll();
    if (params.has("frame")) setIndex(Number(params.get("frame")));
    else if (frames.length) playhead = frames[0].t;
    tick();
  }
  start();
})();
