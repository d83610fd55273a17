// Reason codes in plain language, from /static/reasons.json (shared with the fleet view's
// Python side, relayd/api/reasons.py, which writes the same text for the same document).
"use strict";

const Reasons = (() => {
  const MINUS = "\u2212";
  let phrases = null;

  async function load() {
    try {
      const resp = await fetch("/static/reasons.json", { cache: "no-cache" });
      if (resp.ok) phrases = (await resp.json()).phrases;
    } catch (err) {
      console.warn("reasons.json not loaded: showing raw reason codes", err);
    }
  }

  function num(v) {
    return typeof v === "number" && Number.isFinite(v) ? v : null;
  }

  // Half up on integers, exactly as relayd.api.reasons.fmt_db.
  function fmtDb(value) {
    const tenths = Math.floor(value * 10 + 0.5);
    const a = Math.abs(tenths);
    const whole = Math.floor(a / 10), frac = a % 10;
    const text = frac === 0 ? `${whole}` : `${whole}.${frac}`;
    return tenths >= 0 ? text : MINUS + text;
  }

  function comparison(kind, doc) {
    const thr = doc.thresholds || {};
    const band = num(thr.hysteresis_db) || 0;
    if (kind === "leader") {
      const v = num(doc.rssi_leader_dbm), t = num(thr.threshold_l_dbm);
      if (v === null || t === null) return null;
      return v >= t ? `${fmtDb(v)} dBm \u2265 ${fmtDb(t)}` : `${fmtDb(v)} dBm, drives again below ${fmtDb(t - band)}`;
    }
    if (kind === "rear") {
      const v = num(doc.rssi_behind_dbm), t = num(thr.threshold_b_dbm);
      if (v === null || t === null) return null;
      return v <= t ? `${fmtDb(v)} dBm \u2264 ${fmtDb(t)}` : `${fmtDb(v)} dBm, drives again above ${fmtDb(t + band)}`;
    }
    return null;
  }

  function describe(doc) {
    const reason = String(doc.reason ?? "");
    const colon = reason.indexOf(":");
    const code = (colon < 0 ? reason : reason.slice(0, colon)).trim();
    const entry = phrases && Object.hasOwn(phrases, code) ? phrases[code] : undefined;
    if (!entry) return reason;
    let text = doc.mode === "manual" && entry.manual ? entry.manual : entry.text;
    const detail = entry.detail ? comparison(entry.detail, doc) : colon < 0 ? null : reason.slice(colon + 1).trim();
    if (detail) text = `${text} (${detail})`;
    return text;
  }

  return { load, describe, fmtDb, loaded: () => phrases !== null };
})();
