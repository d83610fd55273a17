"""/status and /metrics across a Linux bridge, from a command-center network namespace.

Three namespaces with unique names per run: `br` holds a bridge, `robot` and `cc` each
have a veth whose peer is a bridge port, addresses from 192.0.2.0/24 (TEST-NET-1) only.
The server runs inside `robot`, bound to its bridge address; the fetch runs inside `cc`
with the venv's Python. Everything is removed in `finally`.

`SERVER_CMD` is the one thing to change to run the real daemon (`relayd run -c ...` on
the fakes) instead of the demo server; it must print a line containing `LISTENING_MARK`
once the API is bound (or adapt `_wait_listening`). Needs root and iproute2: under
CI=true their absence fails the test; locally it skips.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytestmark = pytest.mark.netns

ROOT = Path(__file__).resolve().parent.parent
PYTHON = sys.executable
ROBOT_ADDR = "192.0.2.10"
CC_ADDR = "192.0.2.20"
PREFIX_LEN = 24
API_PORT = 8080
#: The robot-side server, formatted with host/port. Swap for `relayd run` when it lands.
SERVER_CMD = [PYTHON, "-m", "relayd.api.demo", "--host", "{host}", "--port", "{port}"]
LISTENING_MARK = "listening on"

FETCH_SCRIPT = """
import json, sys, urllib.request
base = sys.argv[1]
with urllib.request.urlopen(base + "/status", timeout=5) as r:
    status = json.load(r)
with urllib.request.urlopen(base + "/metrics", timeout=5) as r:
    metrics = r.read().decode()
    ctype = r.headers["Content-Type"]
print(json.dumps({"status": status, "metrics": metrics, "metrics_type": ctype}))
"""


def _need_root() -> None:
    missing = []
    if os.geteuid() != 0:
        missing.append("root")
    if shutil.which("ip") is None:
        missing.append("iproute2 (ip)")
    if not missing:
        return
    message = "network-namespace test needs " + " and ".join(missing)
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail(message)
    pytest.skip(message)


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
        for ns, addr, port_name in ((ns_robot, ROBOT_ADDR, f"r{suffix}"), (ns_cc, CC_ADDR, f"c{suffix}")):
            # eth0 inside the end namespace, its peer is a port of br0.
            _ip("-n", ns, "link", "add", "eth0", "type", "veth", "peer", "name", port_name, "netns", ns_br)
            _ip("-n", ns_br, "link", "set", port_name, "master", "br0")
            _ip("-n", ns_br, "link", "set", port_name, "up")
            _ip("-n", ns, "addr", "add", f"{addr}/{PREFIX_LEN}", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")
            _ip("-n", ns, "link", "set", "lo", "up")
    except RuntimeError as exc:
        for ns in reversed(created):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=10, check=False)
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(f"cannot build the namespaces: {exc}")
        pytest.skip(f"cannot build the namespaces here: {exc}")
    try:
        yield ns_robot, ns_cc
    finally:
        for ns in reversed(created):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=10, check=False)


def _wait_listening(proc: subprocess.Popen[str], timeout_s: float = 20.0) -> None:
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout_s
    seen: list[str] = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            if proc.poll() is not None:
                break
            continue
        seen.append(line)
        if LISTENING_MARK in line:
            return
    raise AssertionError(f"server did not come up (exit {proc.poll()}):\n{''.join(seen)}")


def test_status_and_metrics_across_the_bridge(bridged: tuple[str, str]) -> None:
    ns_robot, ns_cc = bridged
    cmd = [part.format(host=ROBOT_ADDR, port=API_PORT) for part in SERVER_CMD]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "RELAYD_API_TOKEN": "netns-test-token"}
    server = subprocess.Popen(["ip", "netns", "exec", ns_robot, *cmd], cwd=ROOT, env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        _wait_listening(server)
        fetch = subprocess.run(
            ["ip", "netns", "exec", ns_cc, PYTHON, "-c", FETCH_SCRIPT, f"http://{ROBOT_ADDR}:{API_PORT}"],
            capture_output=True, text=True, timeout=30, check=False)
        assert fetch.returncode == 0, fetch.stderr
        result = json.loads(fetch.stdout)
        status = result["status"]
        assert status["state"] in {"driving", "stopped", "avoiding", "leader_lost", "fault"}
        assert len(status["sonar_mm"]) == 16
        assert "netns-test-token" not in fetch.stdout
        assert result["metrics_type"].startswith("text/plain")
        assert "relayd_build_info" in result["metrics"]
        assert "relayd_device_connected" in result["metrics"]

    finally:
        server.terminate()
        try:
            server.wait(10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait(5)
        if server.stdout is not None:
            server.stdout.close()
