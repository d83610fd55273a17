"""The shipped Prometheus and Grafana files (deploy/): valid, and about metrics relayd exports.

promtool (Debian's `prometheus` package, installed by scripts/test) checks the scrape
config and the rules, and proves each alert fires on synthetic series
(deploy/prometheus/relayd-alerts.test.yml). Independently of promtool, every PromQL
expression in the rules and in the Grafana dashboard is parsed here, and each metric
it names, with each label and value it matches on, must be one a relayd really
exports: a renamed metric must break this test, not a dashboard on the day it is needed.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml
from prometheus_client import generate_latest
from prometheus_client.parser import text_string_to_metric_families

from drivers.transport.clock import Clock
from drivers.transport.health import DeviceHealth, LinkState
from relayd.core.vocab import DriveState, Mode, ScanRecord
from relayd.runtime.metrics import Metrics
from relayd.runtime.state import LinkInfo, RelayState
from tests.support import skip_or_fail

ROOT = Path(__file__).resolve().parents[2]
PROM_DIR = ROOT / "deploy" / "prometheus"
SCRAPE_CONFIG = PROM_DIR / "prometheus.yml"
RULES = PROM_DIR / "relayd-alerts.yml"
RULES_TEST = PROM_DIR / "relayd-alerts.test.yml"
DASHBOARD = ROOT / "deploy" / "grafana" / "relayd-convoy.json"
#: Labels Prometheus attaches to every scraped series (job, instance) and ours from the scrape config.
TARGET_LABELS = {"job", "instance", "relay"}
#: Series Prometheus makes itself for each target.
PROMETHEUS_SERIES = {"up": TARGET_LABELS}
PROMQL_KEYWORDS = {
    "by",
    "without",
    "on",
    "ignoring",
    "group_left",
    "group_right",
    "bool",
    "and",
    "or",
    "unless",
    "offset",
    "inf",
    "nan",
    "atan2",
}


def promtool() -> str:
    path = shutil.which("promtool")
    if path is None:
        skip_or_fail(
            "promtool not installed (Debian: apt-get install prometheus; scripts/test does it as root)"
        )
    return path


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, capture_output=True, text=True, timeout=60, check=False)


class _Clock(Clock):
    def now(self) -> float:
        return 100.0


def exported() -> dict[str, dict[str, set[str]]]:
    """Every sample name a relayd exports -> {label: values seen}, over every state and mode."""
    out: dict[str, dict[str, set[str]]] = {}
    for drive in DriveState:
        for mode in Mode:
            st = RelayState(started_t=1.0, mode=mode, state=drive, reason="test")
            st.bearing_deg, st.link_bearing_deg = 10.0, 12.0
            st.rssi_leader_dbm, st.rssi_behind_dbm = -40.0, -55.0
            st.thresholds = {"threshold_l_dbm": -30.0, "threshold_b_dbm": -60.0}
            st.battery_v, st.loop_tick_t = 12.6, 99.0
            st.sonar_mm = [1000] * 16
            st.last_scan = ScanRecord(99.0, (0.0,), (-40.0,), 0.0, -40.0, 0)
            for link in ("front", "rear"):
                st.links[link] = LinkInfo(
                    signal_dbm=-60, ccq_pct=90, tx_mbps=54, rx_mbps=48, t=99.0
                )
            for device in ("robot", "pantilt", "wifi", "ap.rear", "ap.front"):
                st.health[device] = DeviceHealth(device, LinkState.UP, last_rx_t=99.0)
            m = Metrics(st, _Clock())
            m.observe_control_latency(0.0005)
            m.observe_control_step(0.0001)
            m.observe_scan_period(2.0)
            m.sip_received()
            for fam in text_string_to_metric_families(generate_latest(m.registry).decode()):
                for sample in fam.samples:
                    labels = out.setdefault(sample.name, {})
                    for k, v in sample.labels.items():
                        labels.setdefault(k, set()).add(v)
    return out


_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
_SELECTOR = re.compile(r"(?<![\w.:$])([A-Za-z_:][A-Za-z0-9_:]*)?\s*\{([^}]*)\}")
_MATCHER = re.compile(r'([A-Za-z_][A-Za-z0-9_]*)\s*(=~|!~|!=|=)\s*"((?:[^"\\]|\\.)*)"')
_WORD = re.compile(r"(?<![\w.:$])[A-Za-z_:][A-Za-z0-9_:]*")


def metric_names(expr: str) -> set[str]:
    """The series names a PromQL expression selects (functions, keywords, labels left out)."""
    e = _STRING.sub('""', expr)
    e = re.sub(r"\{[^}]*\}", " ", e)
    e = re.sub(r"\[[^\]]*\]", " ", e)
    e = re.sub(r"\b(by|without|on|ignoring|group_left|group_right)\s*\([^)]*\)", " ", e)
    names = set()
    for m in _WORD.finditer(e):
        if e[m.end() :].lstrip().startswith("(") or m.group(0).lower() in PROMQL_KEYWORDS:
            continue
        names.add(m.group(0))
    return names


def selectors(expr: str) -> Iterator[tuple[str, str, str, str]]:
    """(metric, label, operator, value) of every label matcher on a named selector."""
    for m in _SELECTOR.finditer(expr):
        if m.group(1) is None:
            continue
        for lm in _MATCHER.finditer(m.group(2)):
            yield m.group(1), lm.group(1), lm.group(2), lm.group(3)


def test_promql_parser_sees_what_it_must() -> None:
    # The checker itself: a typo in a name or a label value must be visible to it.
    expr = (
        "histogram_quantile(0.99, sum by (relay, le) (rate(relayd_control_latency_seconds_bucket"
        '{relay=~"$relay"}[$__rate_interval]))) > on(relay) group_left relayd_rssi_dbm{peer="behind"} * 1e3'
    )
    assert metric_names(expr) == {"relayd_control_latency_seconds_bucket", "relayd_rssi_dbm"}
    assert set(selectors(expr)) == {
        ("relayd_control_latency_seconds_bucket", "relay", "=~", "$relay"),
        ("relayd_rssi_dbm", "peer", "=", "behind"),
    }
    assert _unknown_references('relayd_rssi_dbm{peer="rear"}', exported())  # no such peer
    assert _unknown_references("relayd_rssi_dbms", exported())


def _unknown_references(expr: str, known: dict[str, dict[str, set[str]]]) -> list[str]:
    known = {**known, **{k: {label: set() for label in v} for k, v in PROMETHEUS_SERIES.items()}}
    problems = [
        f"metric {name} is not exported" for name in sorted(metric_names(expr)) if name not in known
    ]
    for name, label, op, value in selectors(expr):
        if name not in known or label in TARGET_LABELS:
            continue
        if label not in known[name]:
            problems.append(f"{name} has no label {label}")
        elif op == "=" and value not in known[name][label]:
            problems.append(
                f'{name}{{{label}="{value}"}} never exported (has {sorted(known[name][label])})'
            )
    return problems


def _rules() -> list[dict[str, Any]]:
    doc = yaml.safe_load(RULES.read_text(encoding="utf-8"))
    return [rule for group in doc["groups"] for rule in group["rules"]]


# --- promtool ------------------------------------------------------------------------------


def test_promtool_accepts_the_scrape_config_and_its_rules() -> None:
    result = _run(promtool(), "check", "config", str(SCRAPE_CONFIG))
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 rule files found" in result.stdout + result.stderr


def test_promtool_accepts_the_rules() -> None:
    result = _run(promtool(), "check", "rules", str(RULES))
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"{len(_rules())} rules found" in result.stdout + result.stderr


def test_alerts_fire_on_synthetic_series() -> None:
    # promtool runs the rules over the series in the test file and compares the alerts
    # (labels and rendered text) with the expected ones at each evaluation time.
    result = _run(promtool(), "test", "rules", str(RULES_TEST))
    assert result.returncode == 0, result.stdout + result.stderr
    tests = yaml.safe_load(RULES_TEST.read_text(encoding="utf-8"))["tests"]
    fired = {
        case["alertname"] for t in tests for case in t["alert_rule_test"] if case["exp_alerts"]
    }
    quiet = {
        case["alertname"] for t in tests for case in t["alert_rule_test"] if not case["exp_alerts"]
    }
    every = {rule["alert"] for rule in _rules()}
    # Each alert is shown both firing and not yet firing (its hold time matters).
    assert fired == every and quiet == every


# --- the files' content ----------------------------------------------------------------------


def test_the_required_alerts_exist_with_their_hold_times() -> None:
    rules = {rule["alert"]: rule for rule in _rules()}
    assert rules["RelaydStoppedOnFault"]["for"] == "30s"
    assert rules["RelaydRearLinkWeak"]["for"] == "60s"
    assert rules["RelaydFrontLinkWeak"]["for"] == "60s"
    assert "relayd_battery_volts" in rules["RelaydBatteryLow"]["expr"]
    assert rules["RelaydDown"]["expr"].replace(" ", "").startswith('up{job="relayd"}==0')
    for rule in rules.values():
        assert rule["labels"]["severity"] in {"warning", "critical"}
        assert "$labels.relay" in rule["annotations"]["summary"]


def test_alert_expressions_name_exported_metrics() -> None:
    known = exported()
    for rule in _rules():
        assert not _unknown_references(rule["expr"], known), rule["alert"]


def test_scrape_config_labels_every_target_with_its_relay() -> None:
    doc = yaml.safe_load(SCRAPE_CONFIG.read_text(encoding="utf-8"))
    (job,) = [j for j in doc["scrape_configs"] if j["job_name"] == "relayd"]
    relays = [sc["labels"]["relay"] for sc in job["static_configs"]]
    assert len(relays) == len(set(relays)) >= 1
    for sc in job["static_configs"]:
        assert len(sc["targets"]) == 1, "one target per relay label"
    assert doc["rule_files"] == [RULES.name]


def _dashboard() -> dict[str, Any]:
    doc = json.loads(DASHBOARD.read_text(encoding="utf-8"))
    assert isinstance(doc, dict)
    return doc


def _panels(doc: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    for p in doc["panels"]:
        out.append(p)
        out.extend(p.get("panels", []))
    return out


def dashboard_exprs() -> list[tuple[str, str]]:
    """(panel title, expr) of every query in the dashboard, the relay variable's included."""
    doc = _dashboard()
    exprs = [(p["title"], t["expr"]) for p in _panels(doc) for t in p.get("targets", [])]
    for var in doc["templating"]["list"]:
        if var["type"] == "query":
            exprs.append((f"${var['name']}", var["query"]["query"]))
    return exprs


def test_dashboard_uses_a_prometheus_datasource_variable() -> None:
    doc = _dashboard()
    variables = {v["name"]: v for v in doc["templating"]["list"]}
    assert variables["datasource"]["type"] == "datasource"
    assert variables["datasource"]["query"] == "prometheus"
    ds = {"type": "prometheus", "uid": "${datasource}"}
    assert variables["relay"]["datasource"] == ds
    panels = [p for p in _panels(doc) if p["type"] != "row"]
    assert len({p["id"] for p in _panels(doc)}) == len(_panels(doc)), "panel ids must be unique"
    for p in panels:
        assert p["datasource"] == ds, p["title"]
        assert p["targets"], p["title"]
        for t in p["targets"]:
            assert t["datasource"] == ds, p["title"]
        grid = p["gridPos"]
        assert grid["x"] + grid["w"] <= 24 and grid["w"] > 0 and grid["h"] > 0, p["title"]


def test_dashboard_shows_links_states_latency_and_battery() -> None:
    text = " ".join(expr for _, expr in dashboard_exprs())
    for metric in (
        "relayd_rssi_dbm",
        "relayd_rssi_threshold_dbm",
        "relayd_link_signal_dbm",
        "relayd_drive_state",
        "relayd_drive_info",
        "relayd_mode",
        "relayd_control_latency_seconds_bucket",
        "relayd_battery_volts",
        "up",
    ):
        assert re.search(rf"\b{metric}\b", text), metric


def test_dashboard_expressions_name_exported_metrics() -> None:
    known = exported()
    exprs = dashboard_exprs()
    assert len(exprs) >= 10
    for title, expr in exprs:
        if expr.startswith("label_values("):
            # label_values(metric, label): a Grafana function, not PromQL.
            metric, label = (s.strip() for s in expr[len("label_values(") : -1].split(","))
            assert metric in known and label in TARGET_LABELS, title
            continue
        problems = _unknown_references(expr, known)
        assert not problems, f"{title}: {problems}"
