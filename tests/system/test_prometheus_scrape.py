"""The real Prometheus server scrapes a running relayd, with the shipped config and rules.

A relayd `Daemon` drives a `FakeRig`, its API on an ephemeral loopback port. Debian's
`prometheus` binary (installed by scripts/test) runs as a subprocess on another free
loopback port with a temporary storage directory and the shipped
deploy/prometheus/prometheus.yml, changed only where a test must: its one target is the
daemon, scraped every second, and the rules path is absolute. Through Prometheus's HTTP
API the test then reads relayd's metrics back (with the `relay` label the scrape config
adds), sees the shipped rules evaluated without error, and has every dashboard query
accepted and the key ones answered.

Everything is bounded: each wait has a timeout, and the server is terminated (then
killed) in a `finally`. The Debian package's own service is never used (its port and
storage are not ours), so one left running by apt does not matter.
"""

from __future__ import annotations

import asyncio
import contextlib
import shutil
import socket
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from aiohttp import ClientError, ClientSession

from relayd.config.load import parse_settings
from relayd.daemon import Daemon
from relayd.fakes.rig import FakeRig
from tests.support import running, skip_or_fail, until
from tests.system.test_deploy_prometheus import RULES, SCRAPE_CONFIG, dashboard_exprs

# The waits below add up to more than the suite's default 120 s on a loaded machine.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

#: Generous: two cores shared with other test runs.
START_TIMEOUT_S = 45.0
SCRAPE_TIMEOUT_S = 45.0
DISPLAY_NAME = "relay 1 (lab)"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def scrape_config_for(daemon_port: int, rules: Path) -> dict[str, Any]:
    """The shipped scrape config aimed at one loopback relayd, scraped every second."""
    doc = yaml.safe_load(SCRAPE_CONFIG.read_text(encoding="utf-8"))
    doc["global"].update(scrape_interval="1s", scrape_timeout="900ms", evaluation_interval="1s")
    doc["rule_files"] = [str(rules)]
    (job,) = [j for j in doc["scrape_configs"] if j["job_name"] == "relayd"]
    job["static_configs"] = [
        {"targets": [f"127.0.0.1:{daemon_port}"], "labels": {"relay": "relay1"}}
    ]
    return doc


class Prometheus:
    """A prometheus server subprocess and a client for its HTTP API."""

    def __init__(
        self, proc: asyncio.subprocess.Process, url: str, session: ClientSession, log: Path
    ) -> None:
        self.proc, self.url, self.session, self.log = proc, url, session, log

    async def get(self, path: str, **params: str) -> dict[str, Any]:
        async with self.session.get(self.url + path, params=params) as resp:
            doc = await resp.json()
            assert resp.status == 200 and doc["status"] == "success", (path, params, doc)
            assert isinstance(doc, dict)
            return doc

    async def query(self, expr: str) -> list[dict[str, Any]]:
        result: list[dict[str, Any]] = (await self.get("/api/v1/query", query=expr))["data"][
            "result"
        ]
        return result

    def died(self) -> str | None:
        if self.proc.returncode is None:
            return None
        return f"prometheus exited {self.proc.returncode}: {self.log.read_text(errors='replace')[-2000:]}"


@contextlib.asynccontextmanager
async def prometheus(work: Path, config: dict[str, Any]) -> AsyncIterator[Prometheus]:
    binary = shutil.which("prometheus")
    if binary is None:
        skip_or_fail(
            "prometheus not installed (Debian: apt-get install prometheus; scripts/test does it as root)"
        )
    work.mkdir(parents=True, exist_ok=True)
    config_path = work / "prometheus.yml"
    config_path.write_text(yaml.safe_dump(config), encoding="utf-8")
    log = work / "prometheus.log"
    port = _free_port()
    with log.open("wb") as log_file:
        proc = await asyncio.create_subprocess_exec(
            binary,
            f"--config.file={config_path}",
            f"--storage.tsdb.path={work / 'data'}",
            f"--web.listen-address=127.0.0.1:{port}",
            "--log.level=warn",
            stdin=asyncio.subprocess.DEVNULL,
            stdout=log_file,
            stderr=log_file,
        )
    try:
        async with ClientSession() as session:
            server = Prometheus(proc, f"http://127.0.0.1:{port}", session, log)

            async def ready() -> bool:
                if (why := server.died()) is not None:
                    raise AssertionError(why)
                with contextlib.suppress(ClientError, OSError):
                    async with session.get(server.url + "/-/ready") as resp:
                        return resp.status == 200
                return False

            await until(ready, "prometheus to be ready", START_TIMEOUT_S, poll_s=0.25)
            yield server
    finally:
        if proc.returncode is None:
            proc.terminate()
            try:
                await asyncio.wait_for(proc.wait(), 10.0)
            except TimeoutError:
                proc.kill()
                await proc.wait()


async def test_prometheus_scrapes_relayd_and_evaluates_the_shipped_rules(tmp_path: Path) -> None:
    async with FakeRig(tmp_path / "rig") as rig:
        settings = parse_settings(
            rig.config_doc(
                api_port=0, control={"mode": "hold"}, robot={"display_name": DISPLAY_NAME}
            )
        )
        daemon = Daemon(settings, env=rig.env)
        async with running(daemon) as task:
            await until(lambda: daemon.api_port is not None or task.done(), "the API to bind")
            assert daemon.api_port is not None, task.result()
            async with prometheus(
                tmp_path / "prom", scrape_config_for(daemon.api_port, RULES)
            ) as prom:
                await _check(prom, daemon)


async def _check(prom: Prometheus, daemon: Daemon) -> None:
    # 1. A relayd metric, read back through the query API with the scrape config's labels.
    async def uptime() -> list[dict[str, Any]] | None:
        assert prom.died() is None, prom.died()
        return await prom.query('relayd_uptime_seconds{job="relayd", relay="relay1"}') or None

    (series,) = await until(
        uptime, "a scraped relayd_uptime_seconds", SCRAPE_TIMEOUT_S, poll_s=0.25
    )
    assert series["metric"]["instance"] == f"127.0.0.1:{daemon.api_port}"
    assert float(series["value"][1]) > 0
    (up,) = await prom.query('up{job="relayd"}')
    assert up["value"][1] == "1" and up["metric"]["relay"] == "relay1"
    (info,) = await prom.query('relayd_drive_info{relay="relay1"}')
    assert info["metric"]["state"] == str(daemon.state.state) == "stopped"
    assert info["metric"]["reason"] == daemon.state.reason == "hold"
    # The fake base reports its battery and the fake rear radio RSSI^b: both reach Prometheus.
    battery = await until(
        lambda: prom.query("relayd_battery_volts"), "the battery voltage", 20.0, poll_s=0.25
    )
    assert float(battery[0]["value"][1]) == pytest.approx(daemon.state.battery_v or 0, abs=0.2)

    # 2. The shipped rules load and evaluate against real data without errors.
    async def evaluated() -> list[dict[str, Any]] | None:
        groups = (await prom.get("/api/v1/rules"))["data"]["groups"]
        rules = [r for g in groups for r in g["rules"]]
        done = rules and all(not r["lastEvaluation"].startswith("0001") for r in rules)
        return rules if done else None

    rules = await until(evaluated, "every rule to be evaluated once", 20.0, poll_s=0.25)
    assert {r["name"] for r in rules} == {
        r["alert"] for r in yaml.safe_load(RULES.read_text())["groups"][0]["rules"]
    }
    for rule in rules:
        assert rule["health"] == "ok", rule
    # A healthy relay in hold fires nothing.
    assert not [r for r in rules if r["state"] == "firing"], rules

    # 3. Every dashboard query is valid PromQL for this server, and the panels an operator
    # reads first have data.
    answered = {}
    for title, expr in dashboard_exprs():
        if expr.startswith("label_values("):
            continue
        promql = expr.replace("$relay", "relay1").replace("$__rate_interval", "1m")
        answered[title] = await prom.query(promql)
    for title in (
        "Scrape",
        "State and reason now",
        "Mode",
        "Drive state",
        "Battery",
        "RSSI of the leader (Yagi) and of the node behind, with thresholds",
        "Radio links (airOS signal)",
        "Devices connected",
    ):
        assert answered[title], f"dashboard panel {title!r} has no data"
    (state,) = answered["Drive state"]
    assert state["value"][1] == "3"  # the mapping's number for "stopped"
