// The last minutes of the robot, from the daemon's /history ring buffer: RSSI^l and
// RSSI^b against their thresholds, bearing, drive state, and the odometry path trail.
// The page asks once for everything, then every few seconds only for newer samples;
// the buffer lives in the daemon, so a reloaded page has the same past.
"use strict";

const History = (() => {
  const NS = "http://www.w3.org/2000/svg";
  const LEFT = 44, RIGHT = 578;
  const STATE_CLASS = ["driving", "stopped", "avoiding", "leader_lost", "fault"];
  let samples = [];   // {ms, seq, rl, rb, bearing, state, x, y, th}
  let nextAfter = -1;
  let windowMs = 300000;
  let periodMs = 500;
  let thresholds = {};

  function el(tag, attrs, parent) {
    const e = document.createElementNS(NS, tag);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, String(v));
    if (parent) parent.appendChild(e);
    return e;
  }

  async function poll() {
    let body;
    try {
      const resp = await fetch(`/history?after=${nextAfter}`, { cache: "no-store" });
      if (!resp.ok) return false;
      body = await resp.json();
    } catch (err) {
      return false;  // the live stream already says the robot is unreachable
    }
    const now = Date.now();
    const c = body.samples;
    // Sequence numbers going back mean the daemon restarted: its past replaces ours.
    if (c.seq.length && c.seq[0] <= nextAfter) samples = [];
    for (let i = 0; i < c.seq.length; i += 1) {
      samples.push({
        ms: now - c.age_s[i] * 1000, seq: c.seq[i], rl: c.rssi_leader_dbm[i], rb: c.rssi_behind_dbm[i],
        bearing: c.bearing_deg[i], state: c.state[i], x: c.x_mm[i], y: c.y_mm[i], th: c.theta_deg[i],
      });
    }
    if (c.seq.length) nextAfter = c.seq[c.seq.length - 1];
    thresholds = body.thresholds || {};
    windowMs = body.window_s * 1000;
    periodMs = body.period_s * 1000;
    draw();
    return true;
  }

  function xOf(ms, now) {
    return LEFT + ((ms - (now - windowMs)) / windowMs) * (RIGHT - LEFT);
  }

  // A path through the samples, broken where a value is missing or samples are missing.
  function seriesPath(key, yOf, now) {
    let d = "", prevMs = null;
    for (const s of samples) {
      const v = s[key];
      if (typeof v !== "number") { prevMs = null; continue; }
      const gap = prevMs === null || s.ms - prevMs > 3 * periodMs;
      d += `${gap ? "M" : "L"}${xOf(s.ms, now).toFixed(1)} ${yOf(v).toFixed(1)} `;
      prevMs = s.ms;
    }
    return d;
  }

  function axes(g, h, lo, hi, step, unit, now) {
    const yOf = (v) => 8 + (1 - (v - lo) / (hi - lo)) * (h - 24);
    for (let v = lo; v <= hi; v += step) {
      el("line", { x1: LEFT, x2: RIGHT, y1: yOf(v), y2: yOf(v), class: "hgrid" }, g);
      el("text", { x: LEFT - 4, y: yOf(v) + 4, class: "tick-y" }, g).textContent = `${v}${unit}`;
    }
    for (let m = 0; m * 60000 <= windowMs; m += 1) {
      const x = xOf(now - m * 60000, now);
      el("line", { x1: x, x2: x, y1: 8, y2: h - 16, class: "vgrid" }, g);
      el("text", { x, y: h - 3, class: "tick-x" }, g).textContent = m === 0 ? "now" : `\u2212${m} min`;
    }
    return yOf;
  }

  function thresholdLine(g, yOf, value, cls, label) {
    if (typeof value !== "number") return;
    const y = yOf(value);
    el("line", { x1: LEFT, x2: RIGHT, y1: y, y2: y, class: `thr ${cls}` }, g);
    el("text", { x: RIGHT - 2, y: y - 3, class: `thr-label ${cls}` }, g).textContent = label;
  }

  function drawRssi(now) {
    const g = document.getElementById("hist-rssi");
    g.replaceChildren();
    const yOf = axes(g, 170, -100, -20, 20, "", now);
    const clampY = (v) => yOf(Math.min(-20, Math.max(-100, v)));
    const tl = thresholds.threshold_l_dbm, tb = thresholds.threshold_b_dbm;
    if (typeof tl === "number") thresholdLine(g, yOf, tl, "leader", `leader near at \u2265 ${Reasons.fmtDb(tl)}`);
    if (typeof tb === "number") thresholdLine(g, yOf, tb, "behind", `behind weak at \u2264 ${Reasons.fmtDb(tb)}`);
    el("path", { d: seriesPath("rl", clampY, now), class: "series leader", id: "hist-rl" }, g);
    el("path", { d: seriesPath("rb", clampY, now), class: "series behind", id: "hist-rb" }, g);
  }

  function drawBearing(now) {
    const g = document.getElementById("hist-bearing");
    g.replaceChildren();
    const yOf = axes(g, 170, -90, 90, 45, "\u00b0", now);
    el("path", { d: seriesPath("bearing", (v) => yOf(Math.min(90, Math.max(-90, v))), now),
      class: "series bearing", id: "hist-bearing-line" }, g);
  }

  function drawStates(now) {
    const g = document.getElementById("hist-state");
    g.replaceChildren();
    samples.forEach((s, i) => {
      const next = samples[i + 1];
      const end = next && next.ms - s.ms <= 3 * periodMs ? next.ms : s.ms + periodMs;
      const x0 = xOf(s.ms, now), x1 = xOf(end, now);
      if (x1 < LEFT) return;
      const cls = STATE_CLASS.includes(s.state) ? s.state : "unknown";
      el("rect", { x: Math.max(LEFT, x0).toFixed(1), y: 2, width: Math.max(0.5, x1 - Math.max(LEFT, x0)).toFixed(1),
        height: 18, class: `band band-${cls}`, "data-state": s.state }, g);
    });
  }

  // Odometry frame to screen as the sonar view does: forward (x) up, left (y) left.
  function drawPath(live) {
    const svg = document.getElementById("path");
    const g = document.getElementById("path-layer");
    g.replaceChildren();
    const pts = samples.filter((s) => typeof s.x === "number" && typeof s.y === "number")
      .map((s) => [-s.y / 1000, -s.x / 1000, s.th]);
    if (live && typeof live.x_mm === "number" && typeof live.y_mm === "number") {
      pts.push([-live.y_mm / 1000, -live.x_mm / 1000, live.theta_deg]);
    }
    const meta = document.getElementById("path-meta");
    if (!pts.length) { meta.textContent = "no odometry yet"; return; }
    let [x0, y0, x1, y1] = [Infinity, Infinity, -Infinity, -Infinity];
    for (const [x, y] of pts) { x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); }
    const span = Math.max(2, x1 - x0, y1 - y0) * 1.15;
    const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
    svg.setAttribute("viewBox", `${(cx - span / 2).toFixed(3)} ${(cy - span / 2).toFixed(3)} ${span.toFixed(3)} ${span.toFixed(3)}`);
    const step = span > 40 ? 10 : span > 15 ? 5 : 1;
    for (let v = Math.ceil((cx - span / 2) / step) * step; v <= cx + span / 2; v += step) {
      el("line", { x1: v, x2: v, y1: cy - span / 2, y2: cy + span / 2, class: "grid" }, g);
    }
    for (let v = Math.ceil((cy - span / 2) / step) * step; v <= cy + span / 2; v += step) {
      el("line", { x1: cx - span / 2, x2: cx + span / 2, y1: v, y2: v, class: "grid" }, g);
    }
    el("polyline", { points: pts.map(([x, y]) => `${x.toFixed(3)},${y.toFixed(3)}`).join(" "), class: "trail", id: "trail" }, g);
    el("circle", { cx: pts[0][0], cy: pts[0][1], r: span / 90, class: "start" }, g);
    const [hx, hy, th] = pts[pts.length - 1];
    const a = ((typeof th === "number" ? th : 0) * Math.PI) / 180, s = span / 30;
    // Heading theta (ccw from the odometry x axis) on screen: forward (-sin a, -cos a).
    const fx = -Math.sin(a), fy = -Math.cos(a);
    el("path", { d: `M ${hx + fx * s * 1.6} ${hy + fy * s * 1.6} L ${hx - fx * s - fy * s * 0.8} ${hy - fy * s + fx * s * 0.8} `
      + `L ${hx - fx * s + fy * s * 0.8} ${hy - fy * s - fx * s * 0.8} Z`, class: "robot", id: "path-robot" }, g);
    let travelled = 0;
    for (let i = 1; i < pts.length; i += 1) travelled += Math.hypot(pts[i][0] - pts[i - 1][0], pts[i][1] - pts[i - 1][1]);
    meta.textContent = `grid ${step} m \u00b7 ${travelled.toFixed(1)} m in the last ${Math.round(windowMs / 60000)} min`;
  }

  let live = null;
  function draw() {
    const now = Date.now();
    samples = samples.filter((s) => s.ms >= now - windowMs);
    drawRssi(now);
    drawBearing(now);
    drawStates(now);
    drawPath(live);
    const c = document.getElementById("hist-count");
    c.textContent = `${samples.length} samples`;
  }

  function setLive(pose) { live = pose; }

  return { poll, draw, setLive, count: () => samples.length };
})();
