// The operator's buttons: HOLD (stop, no questions asked), follow and manual (each
// confirmed first, since the robot will move). The API token is typed once and kept in
// sessionStorage: it lives as long as this tab and never goes to disk or another tab.
// Every answer is shown as the API gave it, and so is a request that never arrived.
"use strict";

const Control = (() => {
  const KEY = "relayd-api-token";
  const TIMEOUT_MS = 4000;
  const CONFIRM = {
    follow: "Switch to FOLLOW? The robot will drive by itself towards the leader.",
    manual: "Switch to MANUAL? The robot will take drive commands from the API.",
  };
  const $ = (id) => document.getElementById(id);

  function token() {
    return sessionStorage.getItem(KEY) || "";
  }

  function showToken() {
    const set = token() !== "";
    $("token-form").hidden = set;
    $("token-set").hidden = !set;
  }

  function result(text, cls) {
    const out = $("control-result");
    out.textContent = text;
    out.className = `control-result ${cls}`;
  }

  async function send(mode) {
    const tok = token();
    // A stop needs no token (stopping is always safe): it is sent at once, token or not.
    if (!tok && mode !== "hold") {
      result(`${mode}: not sent, enter the API token first`, "bad");
      $("token-input").focus();
      return;
    }
    const stamp = new Date().toLocaleTimeString();
    result(`${mode}: sending\u2026`, "pending");
    const abort = new AbortController();
    const timer = setTimeout(() => abort.abort(), TIMEOUT_MS);
    let resp;
    try {
      resp = await fetch("/api/mode", {
        method: "POST", signal: abort.signal, cache: "no-store",
        headers: tok
          ? { "Content-Type": "application/json", Authorization: `Bearer ${tok}` }
          : { "Content-Type": "application/json" },
        body: JSON.stringify({ mode }),
      });
    } catch (err) {
      const why = abort.signal.aborted ? `no answer within ${TIMEOUT_MS / 1000} s` : "network error, the robot did not answer";
      result(`${mode} NOT confirmed (${stamp}): ${why}`, "bad");
      return;
    } finally {
      clearTimeout(timer);
    }
    let body = null;
    try { body = await resp.json(); } catch (err) { body = null; }
    if (resp.ok) {
      result(`${mode}: accepted by the robot (HTTP ${resp.status}, ${stamp})`, "ok");
      return;
    }
    const msg = body && body.error ? body.error : resp.statusText;
    const hint = resp.status === 401 ? " \u2014 check the token" : "";
    result(`${mode} refused (${stamp}): HTTP ${resp.status} ${msg}${hint}`, "bad");
  }

  function ask(mode) {
    const dialog = $("confirm");
    $("confirm-text").textContent = CONFIRM[mode];
    $("confirm-yes").textContent = `Yes, ${mode}`;
    dialog.dataset.mode = mode;
    dialog.showModal();
  }

  function init() {
    showToken();
    $("btn-hold").addEventListener("click", () => send("hold"));
    $("btn-follow").addEventListener("click", () => ask("follow"));
    $("btn-manual").addEventListener("click", () => ask("manual"));
    $("confirm").addEventListener("close", () => {
      const dialog = $("confirm");
      if (dialog.returnValue === "yes") send(dialog.dataset.mode);
      else result(`${dialog.dataset.mode}: cancelled, nothing sent`, "muted");
      dialog.returnValue = "";
    });
    $("token-form").addEventListener("submit", (ev) => {
      ev.preventDefault();
      const value = $("token-input").value.trim();
      if (!value) return;
      sessionStorage.setItem(KEY, value);
      $("token-input").value = "";
      showToken();
      result("token kept for this tab", "muted");
    });
    $("token-forget").addEventListener("click", () => {
      sessionStorage.removeItem(KEY);
      showToken();
      result("token forgotten", "muted");
    });
  }

  return { init, send };
})();
