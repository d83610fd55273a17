// relayd live page: renders /status documents pushed over /events (Server-Sent Events).
// No framework, no CDN: the page must work on a laptop with no internet in a corridor.
// Every value from the robot is written with textContent / attributes, never as HTML.
// The page never lies about freshness: with no event for STALE_AFTER_MS (the daemon
// sends a heartbeat every second while nothing changes) or a broken stream, it greys
// out, says how old the data is, and shows no state or wheel speed as current.
"use strict";

const SVG_NS = "http://www.w3.org/2000/svg";
// Polar plot: radius in SVG units and the fixed RSSI scale it shows (centre .. rim).
const POLAR_R = 200;
const RSSI_LO_DBM = -100;
const RSSI_HI_DBM = -10;
// Sonar view: half-width in mm; longer ranges are drawn to the rim.
const SONAR_VIEW_MM = 2200;
// P3-AT sonar poses (x forward, y left, mm; heading deg ccw) from ARIA p3at.p.
const SONAR_POSES = [
  [147, 136, 90], [193, 119, 50], [227, 79, 30], [245, 27, 10],
  [245, -27, -10], [227, -79, -30], [193, -119, -50], [147, -136, -90],
  [-144, -136, -90], [-189, -119, -130], [-223, -79, -150], [-241, -27, -170],
  [-241, 27, 170], [-223, 79, 150], [-189, 119, 130], [-144, 136, 90],
];
// No event (status or heartbeat) for this long means the data is not current.
const STALE_AFTER_MS = 2000;
// Sonar ranges at or over this mean no echo (ARIA's maximum): nothing to label.
const NO_ECHO_MM = 5000;

const $ = (id) => document.getElementById(id);
let lastMessageMs = 0;
let lastDoc = null;
let streamBroken = true;
let isStale = true;

function svg(tag, attrs, parent) {
  const el = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, String(v));
  if (parent) parent.appendChild(el);
  return el;
}

function fmt(value, digits, unit) {
  if (value === null || value === undefined || Number.isNaN(value)) return "—";
  const sep = unit && unit !== "°" && unit !== "%" ? " " : "";
  return `${Number(value).toFixed(digits)}${unit ? sep + unit : ""}`;
}

function setText(id, text) {
  const el = $(id);
  if (el.textContent !== text) el.textContent = text;
}

// Robot frame (angle ccw from forward) -> screen: forward is up, left is left.
function polarXY(angleDeg, radius) {
  const a = (angleDeg * Math.PI) / 180;
  return [-radius * Math.sin(a), -radius * Math.cos(a)];
}

function rssiRadius(rssi) {
  const f = (rssi - RSSI_LO_DBM) / (RSSI_HI_DBM - RSSI_LO_DBM);
  return POLAR_R * Math.min(1, Math.max(0, f));
}

function drawPolarGrid(thresholdL) {
  const g = $("polar-grid");
  g.replaceChildren();
  for (let dbm = -90; dbm <= -10; dbm += 20) {
    const r = rssiRadius(dbm);
    svg("path", { d: `M ${-r} 0 A ${r} ${r} 0 0 1 ${r} 0`, class: "ring" }, g);
    svg("text", { x: 3, y: -r + 11, class: "ring-label" }, g).textContent = `${dbm}`;
  }
  for (let a = -90; a <= 90; a += 30) {
    const [x, y] = polarXY(a, POLAR_R);
    svg("line", { x1: 0, y1: 0, x2: x, y2: y, class: "spoke" }, g);
    const [lx, ly] = polarXY(a, POLAR_R + 16);
    svg("text", { x: lx, y: ly + 4, class: "angle-label" }, g).textContent = `${a}°`;
  }
  if (typeof thresholdL === "number") {
    const r = rssiRadius(thresholdL);
    svg("path", { d: `M ${-r} 0 A ${r} ${r} 0 0 1 ${r} 0`, class: "threshold", id: "threshold-ring" }, g);
  }
}

function setLine(id, angleDeg) {
  const line = $(id);
  if (typeof angleDeg !== "number") {
    line.setAttribute("visibility", "hidden");
    return;
  }
  const [x, y] = polarXY(angleDeg, POLAR_R);
  line.setAttribute("x2", x.toFixed(1));
  line.setAttribute("y2", y.toFixed(1));
  line.setAttribute("visibility", "visible");
}

let gridThreshold;
function renderScan(s) {
  const thr = s.thresholds ? s.thresholds.threshold_l_dbm : undefined;
  if (gridThreshold !== thr || !$("polar-grid").hasChildNodes()) {
    drawPolarGrid(thr);
    gridThreshold = thr;
  }
  const scan = s.last_scan;
  const pts = [];
  const dots = $("scan-points");
  dots.replaceChildren();
  if (scan && Array.isArray(scan.angles)) {
    const order = scan.angles.map((a, i) => [a, scan.rssi[i]]).filter((p) => typeof p[1] === "number");
    order.sort((p, q) => p[0] - q[0]);
    for (const [a, rssi] of order) {
      const [x, y] = polarXY(a, rssiRadius(rssi));
      pts.push(`${x.toFixed(1)},${y.toFixed(1)}`);
      const dot = svg("circle", { cx: x.toFixed(1), cy: y.toFixed(1), r: 3, class: "scan-dot" }, dots);
      svg("title", {}, dot).textContent = `${a.toFixed(1)}°  ${rssi.toFixed(1)} dBm`;
    }
    setText("scan-meta", `${order.length} samples · ${fmt(scan.age_s, 1, "s")} ago` +
      (scan.period_s ? ` · period ${fmt(scan.period_s, 2, "s")}` : ""));
  } else {
    setText("scan-meta", "no scan yet");
  }
  $("scan-trace").setAttribute("points", pts.join(" "));
  $("scan-fill").setAttribute("d", pts.length ? `M 0 0 L ${pts.join(" L ")} Z` : "");
  setLine("bearing-line", s.bearing_deg);
  setLine("link-line", s.link_bearing_deg);
  setText("bearing", fmt(s.bearing_deg, 1, "°"));
  setText("link-bearing", fmt(s.link_bearing_deg, 1, "°"));
}

function drawSonarGrid() {
  const g = $("sonar-grid");
  if (g.hasChildNodes()) return;
  for (let m = 1; m * 1000 <= SONAR_VIEW_MM; m += 1) {
    svg("circle", { cx: 0, cy: 0, r: m * 1000, class: "ring" }, g);
    svg("text", { x: 30, y: -m * 1000 + 110, class: "sonar-label" }, g).textContent = `${m} m`;
  }
}

function renderSonar(s) {
  drawSonarGrid();
  const g = $("sonar-rays");
  g.replaceChildren();
  const thrO = (s.thresholds && s.thresholds.threshold_o_m ? s.thresholds.threshold_o_m : 0.8) * 1000;
  let frontMin = null;
  SONAR_POSES.forEach(([x, y, th], i) => {
    const range = Array.isArray(s.sonar_mm) ? s.sonar_mm[i] : null;
    const a = (th * Math.PI) / 180;
    // robot frame -> screen: screen x = -y, screen y = -x
    const sx = -y, sy = -x;
    if (typeof range !== "number") {
      svg("circle", { cx: sx, cy: sy, r: 45, class: "sonar-none" }, g);
      return;
    }
    if (i < 8 && range < NO_ECHO_MM && (frontMin === null || range < frontMin)) frontMin = range;
    const reach = Math.min(range, SONAR_VIEW_MM);
    const ex = -(y + reach * Math.sin(a)), ey = -(x + reach * Math.cos(a));
    if (range >= NO_ECHO_MM) {
      // Nothing echoed: a faint dotted ray to the rim, no wedge and no number.
      svg("line", { x1: sx, y1: sy, x2: ex.toFixed(0), y2: ey.toFixed(0), class: "ray noecho" }, g);
      return;
    }
    const cls = range < thrO ? "near" : range < 3000 ? "mid" : "far";
    // The beam is ±15°: draw it as a wedge so a near obstacle reads at a glance.
    const half = (15 * Math.PI) / 180;
    const lx = -(y + reach * Math.sin(a + half)), ly = -(x + reach * Math.cos(a + half));
    const rx = -(y + reach * Math.sin(a - half)), ry = -(x + reach * Math.cos(a - half));
    svg("path", { d: `M ${sx} ${sy} L ${lx.toFixed(0)} ${ly.toFixed(0)} L ${rx.toFixed(0)} ${ry.toFixed(0)} Z`,
      class: `beam ${cls}` }, g);
    svg("line", { x1: sx, y1: sy, x2: ex.toFixed(0), y2: ey.toFixed(0), class: `ray ${cls}` }, g);
    // Labels sit just inside the ray's end and inside the view so none is clipped.
    const lr = Math.min(reach + 160, SONAR_VIEW_MM - 180);
    const tx = -(y + lr * Math.sin(a)), ty = -(x + lr * Math.cos(a)) + 40;
    const label = svg("text", { x: tx.toFixed(0), y: ty.toFixed(0), class: "range-label" }, g);
    label.textContent = (range / 1000).toFixed(2);
  });
  setText("sonar-min", frontMin === null ? "front: no echo" : `front min ${(frontMin / 1000).toFixed(2)} m`);
}

function renderGauge(barId, valId, thrId, rssi, thr, goodWhenBelow) {
  setText(valId, fmt(rssi, 1, "dBm"));
  setText(thrId, fmt(thr, 0, "dBm"));
  const bar = $(barId);
  const frac = (v) => Math.min(1, Math.max(0, (v - RSSI_LO_DBM) / (RSSI_HI_DBM - RSSI_LO_DBM)));
  const fill = bar.querySelector(".fill");
  fill.style.width = typeof rssi === "number" ? `${(frac(rssi) * 100).toFixed(1)}%` : "0";
  const mark = bar.querySelector(".mark");
  mark.style.display = typeof thr === "number" ? "block" : "none";
  if (typeof thr === "number") mark.style.left = `${(frac(thr) * 100).toFixed(1)}%`;
  let cls = "unknown";
  if (typeof rssi === "number" && typeof thr === "number") {
    cls = (goodWhenBelow ? rssi < thr : rssi > thr) ? "go" : "stop";
  }
  bar.className = `bar ${cls}`;
}

function fillTable(id, rows) {
  const body = $(id).querySelector("tbody");
  body.replaceChildren();
  for (const cells of rows) {
    const tr = document.createElement("tr");
    for (const cell of cells) {
      const td = document.createElement("td");
      if (cell && typeof cell === "object") {
        td.textContent = cell.text;
        td.className = cell.cls;
      } else {
        td.textContent = cell;
      }
      tr.appendChild(td);
    }
    body.appendChild(tr);
  }
}

function renderWheel(barId, valId, mmS, vmax) {
  setText(valId, fmt(mmS, 0, "mm/s"));
  const fill = $(barId).querySelector(".fill");
  const f = Math.min(1, Math.abs(mmS || 0) / vmax);
  fill.style.height = `${(f * 50).toFixed(1)}%`;
  fill.style.bottom = mmS >= 0 ? "50%" : `${(50 - f * 50).toFixed(1)}%`;
  fill.className = mmS >= 0 ? "fill fwd" : "fill rev";
}

// Recovery (self-healing of a broken link): phase badge and the running episode's progress
// against its limits; hidden while recovery is disabled in the config.
function renderRecovery(r) {
  const box = $("recovery-box");
  box.hidden = !r;
  if (!r) return;
  const what = r.kind === "rear" ? "link behind" : r.kind === "leader" ? "leader" : "";
  setText("recovery-phase", r.phase === "idle" ? "idle" : `${r.phase.replace("_", " ")}${what ? " · " + what : ""}`);
  $("recovery-phase").className = `badge recovery-${r.phase}`;
  let text = "";
  if (r.elapsed_s !== null && r.elapsed_s !== undefined) {
    text = `${fmt(r.elapsed_s, 0, "s")} of ${fmt(r.max_time_s, 0, "s")}, ` +
      `${fmt(r.distance_m, 1, "m")} of ${fmt(r.max_distance_m, 1, "m")}`;
  } else if (r.last_outcome) {
    text = `last: ${r.last_outcome.replaceAll("_", " ")} (${r.episodes} episode${r.episodes === 1 ? "" : "s"})`;
  }
  text += ` · trail ${r.trail_crumbs} crumbs`;
  setText("recovery-progress", text);
}

// Everything that carries an age, aged by `extraS` seconds: while the page has no
// current data, ages keep growing from the last update instead of freezing at "0.0 s".
function renderAges(s, extraS, stale) {
  const plus = (age) => (typeof age === "number" ? age + extraS : age);
  fillTable("links", Object.entries(s.links || {}).map(([name, l]) => [
    name, fmt(l.signal_dbm, 0), fmt(l.noise_dbm, 0), fmt(l.ccq_pct, 0),
    fmt(l.tx_mbps, 1), fmt(l.rx_mbps, 1), fmt(plus(l.age_s), 1),
  ]));
  fillTable("health", Object.entries(s.health || {}).map(([name, h]) => [
    name,
    stale ? { text: "unknown", cls: "unknown" }
      : { text: h.connected ? "up" : "down", cls: h.connected ? "ok" : "bad" },
    fmt(plus(h.age_s), 2), String(h.errors), String(h.reconnects), h.last_error || "",
  ]));
  const scan = s.last_scan;
  if (scan && Array.isArray(scan.angles)) {
    const n = (scan.rssi || []).filter((v) => typeof v === "number").length;
    setText("scan-meta", `${n} samples · ${fmt(plus(scan.age_s), 1, "s")} ago` +
      (scan.period_s ? ` · period ${fmt(scan.period_s, 2, "s")}` : ""));
  }
}

function render(s) {
  const name = s.display_name || s.robot;
  setText("robot-name", name || "unnamed robot");
  document.title = `relayd · ${name || ""} · ${s.state}`;
  setText("mode", s.mode);
  $("mode").className = `badge mode-${s.mode}`;
  setText("drive-state", s.state);
  $("drive-state").className = `badge state-${s.state}`;
  setText("situation", ["clear", "avoiding", "obstacle penalty"][s.situation] || String(s.situation));
  $("situation").className = `badge situation-${s.situation}`;
  setText("reason", Reasons.describe(s));
  setText("reason-code", s.reason);
  setText("version", s.version);
  renderRecovery(s.recovery);

  renderScan(s);
  renderSonar(s);

  const thr = s.thresholds || {};
  renderGauge("bar-l", "rssi-l", "thr-l", s.rssi_leader_dbm, thr.threshold_l_dbm, true);
  renderGauge("bar-b", "rssi-b", "thr-b", s.rssi_behind_dbm, thr.threshold_b_dbm, false);
  renderAges(s, 0, false);

  const vmax = thr.v_max_mm_s || 400;
  renderWheel("wheel-l", "wheel-l-val", s.wheels_mm_s.left, vmax);
  renderWheel("wheel-r", "wheel-r-val", s.wheels_mm_s.right, vmax);
  const p = s.pose || {};
  History.setLive(p);
  setText("pose", p.x_mm === null || p.x_mm === undefined ? "—"
    : `x ${fmt(p.x_mm / 1000, 2, "m")}  y ${fmt(p.y_mm / 1000, 2, "m")}  θ ${fmt(p.theta_deg, 0, "°")}`);
  setText("battery", fmt(s.battery_v, 1, "V"));
  setText("motors", s.motors_enabled ? "enabled" : "disabled");
  setText("scan-count", String(s.scan_count));
  setText("uptime", fmt(s.uptime_s, 0, "s"));


}

function markLive() {
  lastMessageMs = Date.now();
  streamBroken = false;
  checkStale();
}

function ago() {
  return lastMessageMs ? `last update ${Math.floor((Date.now() - lastMessageMs) / 1000)} s ago` : "no update yet";
}

// What may not be shown as current once the data is old: state, mode, wheels, devices.
function blankCurrent() {
  for (const id of ["mode", "drive-state", "situation"]) {
    setText(id, "unknown");
    $(id).className = "badge state-unknown";
  }
  document.title = `relayd · ${lastDoc ? lastDoc.display_name || lastDoc.robot || "" : ""} · no current data`;
  for (const [bar, val] of [["wheel-l", "wheel-l-val"], ["wheel-r", "wheel-r-val"]]) {
    setText(val, "—");
    $(bar).querySelector(".fill").style.height = "0";
  }
  setText("motors", "unknown");
  setText("uptime", "unknown");
  const last = lastDoc ? `last known: ${Reasons.describe(lastDoc)}` : "nothing received yet";
  setText("reason", `no current data \u00b7 ${last}`);
}

function checkStale() {
  const old = !lastMessageMs || Date.now() - lastMessageMs > STALE_AFTER_MS;
  const stale = old || streamBroken;
  if (stale) {
    $("live-dot").className = "dot stale";
    setText("live-text", streamBroken && lastMessageMs ? `connection lost · ${ago()}` : ago());
    setText("stale-age", lastMessageMs ? `The last update came ${Math.floor((Date.now() - lastMessageMs) / 1000)} s ago.` : "No update yet.");
    if (!isStale) blankCurrent();
    if (lastDoc && lastMessageMs) renderAges(lastDoc, (Date.now() - lastMessageMs) / 1000, true);
  } else {
    $("live-dot").className = "dot live";
    setText("live-text", "live");
  }
  if (stale !== isStale) {
    isStale = stale;
    document.body.classList.toggle("stale", stale);
    $("stale-banner").hidden = !stale;
    if (!stale && lastDoc) render(lastDoc);
  }
}

function connect() {
  const es = new EventSource("/events");
  es.addEventListener("status", (ev) => {
    try {
      lastDoc = JSON.parse(ev.data);
    } catch (err) {
      console.error("bad status event", err);
      return;
    }
    markLive();
    if (!isStale) render(lastDoc);
  });
  es.addEventListener("heartbeat", markLive);
  es.onerror = () => {
    // The browser retries by itself; until then nothing on the page is current.
    streamBroken = true;
    checkStale();
  };
}

document.addEventListener("DOMContentLoaded", () => {
  drawPolarGrid(undefined);
  drawSonarGrid();
  Control.init();
  Reasons.load().then(() => { if (lastDoc && !isStale) render(lastDoc); });
  connect();
  History.poll();
  setInterval(checkStale, 250);
  setInterval(() => History.draw(), 1000);
  setInterval(() => History.poll(), 2000);
});
