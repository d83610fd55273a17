// relayd fleet page: the chain from the leader through the relays to the command center.
// Polls /fleet.json (the fleet server polls each relay on its own task); no CDN, no
// framework. Values from relays are written with textContent, never as HTML.
"use strict";

const POLL_MS = 500;
const STALE_AFTER_MS = 2000;
const NS = "http://www.w3.org/2000/svg";
const LINK_TEXT = {
  live: "live", stale: "slow: no fresh answer", no_answer: "NO ANSWER", unreachable: "UNREACHABLE",
  bad_answer: "BAD ANSWER", connecting: "connecting…",
};
const $ = (id) => document.getElementById(id);
let lastOkMs = 0;

function h(tag, cls, text, parent) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined && text !== null) e.textContent = text;
  if (parent) parent.appendChild(e);
  return e;
}

function s(tag, attrs, parent) {
  const e = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, String(v));
  if (parent) parent.appendChild(e);
  return e;
}

function fmt(v, digits, unit) {
  if (typeof v !== "number" || !Number.isFinite(v)) return "—";
  return `${v.toFixed(digits)}${unit ? " " + unit : ""}`;
}

function hopQuality(dbm) {
  if (typeof dbm !== "number") return "unknown";
  return dbm >= -65 ? "good" : dbm >= -77 ? "fair" : dbm >= -82 ? "poor" : "down";
}

function renderHop(hop, index, parent) {
  const el = h("div", `hop hop-${hopQuality(hop.rssi_dbm)}`, null, parent);
  el.dataset.index = String(index);
  h("div", "hop-line", null, el);
  h("div", "rssi", typeof hop.rssi_dbm === "number" ? fmt(hop.rssi_dbm, 0, "dBm") : "unknown", el);
  h("div", "rate", typeof hop.est_mbps === "number" ? `≈ ${fmt(hop.est_mbps, 0, "Mb/s")}` : "", el);
  el.title = hop.measurements.length
    ? hop.measurements.map((m) => `${m.by}: ${m.dbm.toFixed(0)} dBm`).join("\n")
    : "no current measurement of this hop";
}

function fact(dl, name, value, cls) {
  h("dt", null, name, dl);
  h("dd", cls || null, value, dl);
}

function renderRelay(r, parent) {
  const card = h("div", `node relay-card ${r.current ? "current" : "not-current"}`, null, parent);
  card.dataset.name = r.name;
  h("div", "name", r.robot && r.robot !== r.name ? `${r.name} (${r.robot})` : r.name, card);
  const link = h("div", `link link-${r.link}`, LINK_TEXT[r.link] || r.link, card);
  if (r.error) link.title = r.error;
  if (!r.current && r.error) h("div", "error", r.error, card);
  const state = h("div", `state badge state-${r.current ? r.state : "unknown"}`,
    r.current ? r.state : "unknown", card);
  if (!r.current && r.state) state.title = `last known: ${r.state}`;
  h("div", "reason", r.current ? r.reason_text : (r.reason_text ? `last known: ${r.reason_text}` : "no data"), card);
  const dl = h("dl", "facts", null, card);
  fact(dl, "mode", r.current ? r.mode : "unknown", "mode");
  fact(dl, "battery", fmt(r.battery_v, 1, "V"), "battery");
  fact(dl, "age", r.age_s === null ? "never" : `${r.age_s.toFixed(1)} s`, "age");
  fact(dl, "RSSI l/b", `${fmt(r.rssi_leader_dbm, 0)} / ${fmt(r.rssi_behind_dbm, 0)} dBm`, "rssi");
}

function renderChain(doc) {
  const chain = $("chain");
  chain.replaceChildren();
  h("div", "node endpoint", "leader", chain);
  doc.hops.forEach((hop, i) => {
    renderHop(hop, i, chain);
    if (i < doc.relays.length) renderRelay(doc.relays[i], chain);
  });
  h("div", "node endpoint", "command center", chain);
  const live = doc.relays.filter((r) => r.current).length;
  $("summary").textContent = `${live} of ${doc.relays.length} relays live`;
}

function renderMap(map) {
  const layer = $("map-layer");
  layer.replaceChildren();
  const pts = [];
  for (const r of map.relays) {
    pts.push([r.x_m, r.y_m]);
    for (const p of r.trail) pts.push(p);
  }
  // Map frame: x east-ish to the right, y up (screen y is flipped).
  let [x0, y0, x1, y1] = [-1, -1, 1, 1];
  if (pts.length) {
    x0 = Math.min(...pts.map((p) => p[0])); x1 = Math.max(...pts.map((p) => p[0]));
    y0 = Math.min(...pts.map((p) => p[1])); y1 = Math.max(...pts.map((p) => p[1]));
  }
  const span = Math.max(4, x1 - x0, y1 - y0) * 1.6;  // room for the labels
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
  $("map").setAttribute("viewBox", `${(cx - span / 2).toFixed(2)} ${(-cy - span / 2).toFixed(2)} ${span.toFixed(2)} ${span.toFixed(2)}`);
  const step = span > 40 ? 10 : span > 15 ? 5 : 1;
  for (let v = Math.ceil((cx - span / 2) / step) * step; v <= cx + span / 2; v += step) {
    s("line", { x1: v, x2: v, y1: -cy - span / 2, y2: -cy + span / 2, class: "grid" }, layer);
  }
  for (let v = Math.ceil((cy - span / 2) / step) * step; v <= cy + span / 2; v += step) {
    s("line", { x1: cx - span / 2, x2: cx + span / 2, y1: -v, y2: -v, class: "grid" }, layer);
  }
  const r0 = span / 40;
  for (const r of map.relays) {
    if (r.trail.length > 1) {
      s("polyline", { points: r.trail.map(([x, y]) => `${x},${-y}`).join(" "), class: "trail" }, layer);
    }
    if (typeof r.leader_deg === "number" && r.current) {
      const a = (r.leader_deg * Math.PI) / 180;
      s("line", { x1: r.x_m, y1: -r.y_m, x2: r.x_m + Math.cos(a) * span / 6, y2: -(r.y_m + Math.sin(a) * span / 6),
        class: "leader-ray" }, layer);
    }
    const a = (r.heading_deg * Math.PI) / 180, c = Math.cos(a), sn = Math.sin(a);
    const tip = [r.x_m + c * r0 * 1.8, r.y_m + sn * r0 * 1.8];
    const left = [r.x_m - c * r0 - sn * r0, r.y_m - sn * r0 + c * r0];
    const right = [r.x_m - c * r0 + sn * r0, r.y_m - sn * r0 - c * r0];
    const g = s("g", { class: `robot state-${r.current ? r.state : "unknown"}`, "data-name": r.name }, layer);
    s("polygon", { points: [tip, left, right].map(([x, y]) => `${x.toFixed(3)},${(-y).toFixed(3)}`).join(" ") }, g);
    const label = s("text", { x: r.x_m + r0 * 1.6, y: -r.y_m - r0 * 1.6, "font-size": r0 * 1.5 }, g);
    label.textContent = r.name;
  }
  $("map-meta").textContent = map.relays.length ? `grid ${step} m` : "no relay can be placed";
  $("map").hidden = map.relays.length === 0;
  const list = $("unplaced");
  list.replaceChildren();
  for (const u of map.unplaced) h("li", null, `${u.name}: not on the map (${u.why})`, list);
}

async function poll() {
  try {
    const resp = await fetch("/fleet.json", { cache: "no-store" });
    if (!resp.ok) throw new Error(`HTTP ${resp.status}`);
    const doc = await resp.json();
    lastOkMs = Date.now();
    renderChain(doc);
    renderMap(doc.map);
  } catch (err) {
    // The fleet server itself is gone: checkStale says so.
  }
  checkStale();
}

function checkStale() {
  const stale = !lastOkMs || Date.now() - lastOkMs > STALE_AFTER_MS;
  document.body.classList.toggle("stale", stale);
  $("stale-banner").hidden = !stale;
  $("live-dot").className = stale ? "dot stale" : "dot live";
  const ago = lastOkMs ? `last update ${Math.floor((Date.now() - lastOkMs) / 1000)} s ago` : "no update yet";
  $("live-text").textContent = stale ? ago : "live";
  $("stale-age").textContent = ago;
}

async function holdAll() {
  const list = $("hold-results");
  list.replaceChildren();
  h("li", "pending", "sending hold to every relay…", list);
  const stamp = new Date().toLocaleTimeString();
  let body;
  try {
    const resp = await fetch("/api/hold-all", {
      method: "POST", cache: "no-store", headers: { "Content-Type": "application/json" }, body: "{}",
    });
    body = await resp.json();
  } catch (err) {
    list.replaceChildren();
    h("li", "bad", `hold NOT sent (${stamp}): the fleet server did not answer`, list);
    return;
  }
  list.replaceChildren();
  for (const r of body.results) {
    const li = h("li", r.ok ? "ok" : "bad", `${r.name}: ${r.message}`, list);
    li.dataset.name = r.name;
  }
  if (!body.results.length) h("li", "bad", "no relays configured", list);
}

document.addEventListener("DOMContentLoaded", () => {
  $("hold-all").addEventListener("click", holdAll);
  poll();
  setInterval(poll, POLL_MS);
  setInterval(checkStale, 250);
});
