"""/status and /metrics of a real relayd, from a command-center network namespace across a Linux bridge.

Three namespaces with unique names per run: `br` holds a bridge, `robot` and `cc` each
have a veth whose peer is a bridge port, addresses from 192.0.2.0/24 (TEST-NET-1) only.
Inside `robot` run `relayd fake rig` (the fake base, servo controller, RSSI file and
airOS radios; the radios listen on the namespace's loopback) and `relayd run -c` on the
config it writes, API bound to the robot's bridge address. From `cc`, the venv's Python
polls /status until the relay reports its name, every device up and scans arriving,
then reads /metrics. Every process and namespace is removed in `finally`.

Needs root and iproute2: under CI=true their absence fails the test; locally it skips.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from tests.support import skip_or_fail, until_sync

pytestmark = pytest.mark.netns

ROOT = Path(__file__).resolve().parents[2]
PYTHON = sys.executable
ROBOT_ADDR = "192.0.2.10"
CC_ADDR = "192.0.2.20"
PREFIX_LEN = 24
API_PORT = 8080
#: Generous: the daemon's first scan takes a few seconds, and the machine is shared.
READY_TIMEOUT_S = 60.0
DEVICES = ("robot", "pantilt", "wifi", "ap.rear", "ap.front")

#: Runs in the cc namespace: poll /status until the relay is up and has finished two
#: scans (so scans are seen *arriving*), then read /metrics. Prints one JSON object.
FETCH_SCRIPT = """
import json, sys, time, urllib.request
base, timeout_s, devices = sys.argv[1], float(sys.argv[2]), sys.argv[3].split(",")
deadline = time.monotonic() + timeout_s
first_scan, status, last_error = None, None, None
while time.monotonic() < deadline:
    try:
        with urllib.request.urlopen(base + "/status", timeout=5) as r:
            status = json.load(r)
    except OSError as exc:
        last_error = repr(exc)
        time.sleep(0.2)
        continue
    up = all(status["health"].get(d, {}).get("connected") for d in devices)
    if up and status["last_scan"] is not None:
        if first_scan is None:
            first_scan = status["scan_count"]
        elif status["scan_count"] > first_scan:
            break
    time.sleep(0.2)
else:
    sys.exit(f"relay not ready in {timeout_s} s; last /status {status!r}; last error {last_error}")
with urllib.request.urlopen(base + "/metrics", timeout=5) as r:
    metrics = r.read().decode()
    ctype = r.headers["Content-Type"]
print(json.dumps({"first_scan": first_scan, "status": status, "metrics": metrics,
                  "metrics_type": ctype}))
"""


def _need_root() -> None:
    missing = []
    if os.geteuid() != 0:
        missing.append("root")
    if shutil.which("ip") is None:
        missing.append("iproute2 (ip)")
    if not missing:
        return
    skip_or_fail("network-namespace test needs " + " and ".join(missing))


def _ip(*args: str) -> None:
    proc = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {proc.stderr.strip()}")


@pytest.fixture
def bridged() -> Iterator[tuple[str, str]]:
    """(robot namespace, cc namespace) joined by a bridge in a third namespace."""
    _need_root()
    suffix = secrets.token_hex(3)
    ns_br, ns_robot, ns_cc = f"relayd-br-{suffix}", f"relayd-robot-{suffix}", f"relayd-cc-{suffix}"
    created: list[str] = []
    try:
        for ns in (ns_br, ns_robot, ns_cc):
            _ip("netns", "add", ns)
            created.append(ns)
        _ip("-n", ns_br, "link", "add", "br0", "type", "bridge")
        _ip("-n", ns_br, "link", "set", "br0", "up")
        for ns, addr, port_name in (
            (ns_robot, ROBOT_ADDR, f"r{suffix}"),
            (ns_cc, CC_ADDR, f"c{suffix}"),
        ):
            # eth0 inside the end namespace, its peer is a port of br0.
            _ip(
                "-n",
                ns,
                "link",
                "add",
                "eth0",
                "type",
                "veth",
                "peer",
                "name",
                port_name,
                "netns",
                ns_br,
            )
            _ip("-n", ns_br, "link", "set", port_name, "master", "br0")
            _ip("-n", ns_br, "link", "set", port_name, "up")
            _ip("-n", ns, "addr", "add", f"{addr}/{PREFIX_LEN}", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")
            _ip("-n", ns, "link", "set", "lo", "up")
    except RuntimeError as exc:
        for ns in reversed(created):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=10, check=False)
        skip_or_fail(f"cannot build the namespaces here: {exc}")
    try:
        yield ns_robot, ns_cc
    finally:
        for ns in reversed(created):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=10, check=False)


def _start(ns: str, args: list[str], log: Path) -> subprocess.Popen[bytes]:
    """`python -m relayd ARGS` inside `ns`, in its own process group, output to `log`."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    with log.open("wb") as out:
        return subprocess.Popen(
            ["ip", "netns", "exec", ns, PYTHON, "-m", "relayd", *args],
            cwd=ROOT,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM its process group (the daemon's safe shutdown), SIGKILL if it lingers."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(10)
            return
        except subprocess.TimeoutExpired:
            pass
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(5)


def _config_path(rig: subprocess.Popen[bytes], out: Path, timeout_s: float = 30.0) -> Path:
    """The config path `relayd fake rig` prints as its first stdout line."""

    def config_or_exit() -> Path | bool | None:
        for line in out.read_text(errors="replace").splitlines():
            if line.endswith(".toml") and Path(line).is_file():
                return Path(line)
        return rig.poll() is not None

    found = until_sync(config_or_exit, "relayd fake rig's config path", timeout_s)
    if not isinstance(found, Path):
        raise AssertionError(
            f"relayd fake rig wrote no config (exit {rig.poll()}):\n{out.read_text()}"
        )
    return found


def test_status_and_metrics_across_the_bridge(bridged: tuple[str, str], tmp_path: Path) -> None:
    ns_robot, ns_cc = bridged
    work = tmp_path / "rig"
    rig_out, run_out = tmp_path / "rig.out", tmp_path / "run.out"
    procs: list[subprocess.Popen[bytes]] = []
    try:
        procs.append(
            _start(
                ns_robot,
                [
                    "fake",
                    "rig",
                    "--dir",
                    str(work),
                    "--api-bind",
                    ROBOT_ADDR,
                    "--api-port",
                    str(API_PORT),
                ],
                rig_out,
            )
        )
        config = _config_path(procs[0], rig_out)
        token = (work / "relay1-api-token").read_text().strip()
        procs.append(_start(ns_robot, ["run", "-c", str(config)], run_out))
        fetch = subprocess.run(
            [
                "ip",
                "netns",
                "exec",
                ns_cc,
                PYTHON,
                "-c",
                FETCH_SCRIPT,
                f"http://{ROBOT_ADDR}:{API_PORT}",
                str(READY_TIMEOUT_S),
                ",".join(DEVICES),
            ],
            capture_output=True,
            text=True,
            timeout=READY_TIMEOUT_S + 30,
            check=False,
        )
        assert fetch.returncode == 0, (
            f"{fetch.stderr}\n--- relayd run:\n{run_out.read_text()}"
            f"\n--- fake rig:\n{rig_out.read_text()}"
        )
        assert procs[1].poll() is None, "relayd run exited"
        result = json.loads(fetch.stdout)
        status = result["status"]
        assert status["robot"] == "relay1"  # the fake base's name, read over its serial link
        assert status["scan_count"] > result["first_scan"] >= 1
        assert len(status["last_scan"]["angles"]) == len(status["last_scan"]["rssi"]) > 0
        assert status["rssi_behind_dbm"] == -55.0  # the rig's rear radio default
        assert status["state"] in {"driving", "stopped", "avoiding", "leader_lost"}
        assert len(status["sonar_mm"]) == 16
        password = (work / "relay1-ap-password").read_text().strip()
        assert token not in fetch.stdout and password not in fetch.stdout
        assert token not in run_out.read_text() and password not in run_out.read_text()

        assert result["metrics_type"].startswith("text/plain")
        samples = {
            (s.name, tuple(sorted(s.labels.items()))): s.value
            for fam in text_string_to_metric_families(result["metrics"])
            for s in fam.samples
        }
        for device in DEVICES:
            assert samples[("relayd_device_connected", (("device", device),))] == 1.0, device
        assert samples[("relayd_sips_received_total", ())] > 0
        assert samples[("relayd_scans_total", ())] >= status["scan_count"]
        assert samples[("relayd_scan_period_seconds_count", ())] >= 1
        assert samples[("relayd_control_latency_seconds_count", ())] > 0
        assert all(name.startswith("relayd_") for name, _ in samples)
    finally:
        # The daemon first (it stops the fake robot's wheels over the link), then the rig.
        for proc in reversed(procs):
            _stop(proc)
