"""systemd/relayd.service beyond its basic directives, and the notify/watchdog contract it relies on.

tests/runtime/test_sdnotify.py already checks the unit's core directives (Type, WatchdogSec,
Restart, User, dialout, ExecStart text, device access, address families) and runs
`systemd-analyze verify`. This file adds:
- the rest of the hardening (the kernel/system sandboxing set below) and that it still lets relayd reach what the
  udev rules name;
- that ExecStart is a command line the real CLI accepts, installed where DEPLOY.md says;
- `systemd-analyze security --offline` exposure, when this systemd can do it offline;
- that `relayd run`, started with ExecStart's arguments the way systemd starts a
  Type=notify unit with WatchdogSec (NOTIFY_SOCKET, WATCHDOG_USEC), sends READY=1 only
  once its API answers, pets the watchdog well inside WatchdogSec, and on SIGTERM sends
  STOPPING=1 and exits 0 within TimeoutStopSec;
- that the watchdog is petted only while the control loop ticks (a wedged loop must
  get the process restarted; a watchdog that pets unconditionally proves nothing).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tomllib
import uuid
from collections.abc import AsyncIterator, Callable, Coroutine
from pathlib import Path
from typing import Any

import pytest
from aiohttp import ClientSession

from relayd.cli import build_parser
from relayd.config.load import parse_settings
from relayd.daemon import WATCHDOG_PET_S, Daemon
from relayd.fakes.rig import FakeRig
from relayd.runtime.control import ControlShell
from relayd.runtime.vtime import LoopClock
from tests.support import parse_unit, skip_or_fail, until

ROOT = Path(__file__).resolve().parents[2]
UNIT = ROOT / "systemd" / "relayd.service"


def _unit() -> dict[str, dict[str, list[str]]]:
    return parse_unit(UNIT.read_text())


def _service(key: str) -> str:
    values = _unit()["Service"].get(key, [])
    assert len(values) == 1, f"{key}: {values}"
    return values[0]


def _seconds(value: str) -> float:
    """A systemd time span such as 5s, 500ms, 1min 30s."""
    units = {"us": 1e-6, "ms": 1e-3, "s": 1.0, "sec": 1.0, "min": 60.0, "m": 60.0, "h": 3600.0}
    total = 0.0
    parts = re.findall(r"(\d+(?:\.\d+)?)\s*([a-z]*)", value)
    assert parts, value
    for number, unit in parts:
        total += float(number) * units[unit or "s"]
    return total


# --- hardening -------------------------------------------------------------------------

#: The unit's kernel/system sandboxing set, each with the value that turns it on.
HARDENING = {
    "ProtectHome": "yes",
    "PrivateTmp": "yes",
    "ProtectKernelTunables": "yes",
    "ProtectKernelModules": "yes",
    "ProtectKernelLogs": "yes",
    "ProtectControlGroups": "yes",
    "ProtectClock": "yes",
    "ProtectHostname": "yes",
    "LockPersonality": "yes",
    "RestrictRealtime": "yes",
    "RestrictNamespaces": "yes",
    "RestrictSUIDSGID": "yes",
    "SystemCallArchitectures": "native",
    "UMask": "0077",
    "RemoveIPC": "yes",
}


def test_hardening_is_complete() -> None:
    for key, value in HARDENING.items():
        assert _service(key) == value, key
    assert "@system-service" in _service("SystemCallFilter").split()
    # A filtered call fails with EPERM instead of killing the robot's daemon mid-drive.
    assert _service("SystemCallErrorNumber") == "EPERM"
    # A private /dev has no serial ports; DynamicUser would drop the dialout membership model.
    svc = _unit()["Service"]
    assert svc.get("PrivateDevices", ["no"]) == ["no"]
    assert "DynamicUser" not in svc


def test_hardening_still_reaches_what_udev_names() -> None:
    """Every serial device the udev rules name is a tty class DeviceAllow opens, in a group
    the service user is in; the config is under ConfigurationDirectory."""
    allowed = {rule.split()[0].removeprefix("char-") for rule in _unit()["Service"]["DeviceAllow"]}
    groups = set(_service("SupplementaryGroups").split()) | {_service("Group")}
    rules = [
        line
        for line in (ROOT / "config" / "99-relayd.rules").read_text().splitlines()
        if line.strip() and not line.lstrip().startswith("#")
    ]
    serial = [r for r in rules if 'SUBSYSTEM=="tty"' in r]
    assert serial
    for rule in serial:
        group = re.search(r'GROUP="([^"]+)"', rule)
        assert group is not None and group.group(1) in groups, rule
    # FTDI (the base's USB-serial) enumerates as ttyUSB, the Maestro as ttyACM (cdc_acm).
    assert {"ttyUSB", "ttyACM"} <= allowed
    config_arg = shlex.split(_service("ExecStart"))[-1]
    assert config_arg.startswith(f"/etc/{_service('ConfigurationDirectory')}/")
    # ProtectSystem=strict leaves /etc read-only: secrets are read, never written.
    assert _service("EnvironmentFile").lstrip("-").startswith("/etc/relayd/")


def test_secrets_file_names_the_variables_the_example_config_uses() -> None:
    """The unit's comment documents what goes in EnvironmentFile; it must match the config."""
    unit_text = UNIT.read_text()
    config = tomllib.loads((ROOT / "config" / "relayd.toml").read_text())
    names = [config["api"].get("token_env")]
    names += [config["ap"][side].get("password_env") for side in ("rear", "front")]
    for name in filter(None, names):
        assert name in unit_text, name


# --- ExecStart ---------------------------------------------------------------------------


def test_execstart_is_a_relayd_run_the_cli_accepts() -> None:
    argv = shlex.split(_service("ExecStart"))
    exe = Path(argv[0])
    assert exe.name == "relayd" and exe.is_absolute()
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["relayd"] == "relayd.__main__:entry"
    args = build_parser().parse_args(argv[1:])
    assert args.command == "run"
    assert args.config == "/etc/relayd/relayd.toml"
    # The venv the unit runs from is the one the deployment guide installs.
    venv = str(exe.parent.parent)
    assert f"python3 -m venv {venv}" in (ROOT / "docs" / "DEPLOY.md").read_text()


# --- systemd-analyze security ------------------------------------------------------------


def test_systemd_analyze_security_exposure(tmp_path: Path) -> None:
    if shutil.which("systemd-analyze") is None:
        skip_or_fail("systemd-analyze not installed (apt-get install systemd)")
    unit = tmp_path / "relayd.service"
    unit.write_text(
        UNIT.read_text().replace("/opt/relayd/venv/bin/relayd", shutil.which("true") or "/bin/true")
    )
    proc = subprocess.run(
        ["systemd-analyze", "security", "--offline=true", "--no-pager", str(unit)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    found = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", proc.stdout)
    if found is None:
        skip_or_fail(
            f"this systemd-analyze cannot rate a unit offline: {proc.stderr.strip()[:200]}"
        )
    # systemd rates 0-10; below 3 is "OK". Serial access needs some exposure (no PrivateDevices).
    assert float(found.group(1)) < 3.0, proc.stdout


# --- the notify protocol, as systemd would see it ------------------------------------------


class NotifySocket:
    """An abstract-namespace datagram socket collecting (loop time, {KEY: value}) messages."""

    def __init__(self) -> None:
        self.name = f"@relayd-test-{uuid.uuid4().hex}"
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind("\0" + self.name[1:])
        self.sock.setblocking(False)
        self.messages: list[tuple[float, dict[str, str]]] = []
        #: Called synchronously as each message arrives, before anything else runs.
        self.on_message: Callable[[dict[str, str]], None] | None = None
        self._new = asyncio.Event()
        self._task = asyncio.create_task(self._collect())

    async def _collect(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            data = await loop.sock_recv(self.sock, 4096)
            fields = dict(line.split("=", 1) for line in data.decode().splitlines())
            self.messages.append((loop.time(), fields))
            if self.on_message is not None:
                self.on_message(fields)
            self._new.set()

    def with_key(self, key: str) -> list[tuple[float, dict[str, str]]]:
        return [(t, m) for t, m in self.messages if key in m]

    async def wait_for(self, key: str, timeout_s: float, count: int = 1) -> float:
        """Loop time of the `count`-th message carrying `key`."""
        async with asyncio.timeout(timeout_s):
            while len(self.with_key(key)) < count:
                self._new.clear()
                await self._new.wait()
        return self.with_key(key)[count - 1][0]

    async def close(self) -> None:
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task
        self.sock.close()


@pytest.fixture
async def notify_socket() -> AsyncIterator[NotifySocket]:
    ns = NotifySocket()
    try:
        yield ns
    finally:
        await ns.close()


def _relayd_argv(config: Path) -> list[str]:
    """ExecStart's argv with this venv's relayd and the rig's config in place of /etc's."""
    argv = shlex.split(_service("ExecStart"))
    script = Path(sys.executable).parent / "relayd"
    head = [str(script)] if script.exists() else [sys.executable, "-m", "relayd"]
    rest = argv[1:]
    rest[rest.index("-c") + 1] = str(config)
    return head + rest


async def test_relayd_run_notifies_ready_pets_the_watchdog_and_stops(
    tmp_path: Path, notify_socket: NotifySocket
) -> None:
    watchdog_s = _seconds(_service("WatchdogSec"))
    stop_timeout_s = _seconds(_service("TimeoutStopSec"))
    port = _free_port()
    api_at_ready: list[bool] = []

    def check_api(fields: dict[str, str]) -> None:
        # READY promises the API is bound: connect the moment it arrives (blocking, on
        # purpose: nothing else runs in between).
        if "READY" in fields:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=2.0).close()
                api_at_ready.append(True)
            except OSError:
                api_at_ready.append(False)

    notify_socket.on_message = check_api
    async with FakeRig(tmp_path) as rig:
        config = rig.write_config(secrets_in_files=True, api_port=port)
        env = {k: v for k, v in os.environ.items() if not k.startswith(("NOTIFY_", "WATCHDOG_"))}
        for assignment in _unit()["Service"].get("Environment", []):
            key, _, value = assignment.partition("=")
            env[key] = value
        env.update(NOTIFY_SOCKET=notify_socket.name, WATCHDOG_USEC=str(round(watchdog_s * 1e6)))
        out = (tmp_path / "relayd.log").open("wb")
        proc = await asyncio.create_subprocess_exec(
            *_relayd_argv(config),
            cwd=tmp_path,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
        try:
            await notify_socket.wait_for("READY", 30.0)
            assert api_at_ready == [True], "READY=1 before the API was listening"
            async with (
                ClientSession() as session,
                session.get(f"http://127.0.0.1:{port}/status") as resp,
            ):
                assert resp.status == 200
                assert (await resp.json())["uptime_s"] >= 0

            # Pets keep coming, far more often than WatchdogSec would fire.
            first = await notify_socket.wait_for("WATCHDOG", 15.0)
            last = await notify_socket.wait_for(
                "WATCHDOG", 15.0, count=len(notify_socket.with_key("WATCHDOG")) + 4
            )
            pets = [t for t, _ in notify_socket.with_key("WATCHDOG") if first <= t <= last]
            gaps = [b - a for a, b in itertools.pairwise(pets)]
            assert max(gaps) < watchdog_s / 2, gaps
            assert all(m["WATCHDOG"] == "1" for _, m in notify_socket.with_key("WATCHDOG"))

            proc.send_signal(signal.SIGTERM)
            loop = asyncio.get_running_loop()
            t0 = loop.time()
            await notify_socket.wait_for("STOPPING", stop_timeout_s)
            code = await asyncio.wait_for(proc.wait(), stop_timeout_s)
            assert code == 0
            assert loop.time() - t0 < stop_timeout_s
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
            out.close()
    assert len(notify_socket.with_key("READY")) == 1
    assert [m["READY"] for _, m in notify_socket.with_key("READY")] == ["1"]
    # READY comes before STOPPING, and the secrets never travel to systemd.
    assert notify_socket.with_key("READY")[0][0] < notify_socket.with_key("STOPPING")[0][0]
    sent = repr(notify_socket.messages)
    assert rig.api_token not in sent and rig.ap_password not in sent


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


# --- the watchdog is petted only while the control loop ticks -------------------------------


class RecordingNotifier:
    def __init__(self) -> None:
        self.calls: list[str] = []

    def ready(self) -> None:
        self.calls.append("ready")

    def status(self, text: str) -> None:
        self.calls.append("status")

    def stopping(self) -> None:
        self.calls.append("stopping")

    def watchdog(self) -> None:
        self.calls.append("watchdog")

    @property
    def pets(self) -> int:
        return self.calls.count("watchdog")


@pytest.mark.virtual_time
async def test_watchdog_pets_only_while_the_control_loop_ticks(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The control task is held back, then runs, then wedges; pets follow the ticks.

    In virtual time, the rig's robot and servo on memory links: the pet periods waited
    out to see an absence cost no wall time.
    """
    release, wedge = asyncio.Event(), asyncio.Event()
    original_run = ControlShell.run

    def gated_run(self: ControlShell) -> Coroutine[Any, Any, None]:
        async def run() -> None:
            await release.wait()
            inner = asyncio.create_task(original_run(self))
            await wedge.wait()
            # A wedged loop: no tick, no SIP-driven step, but the task never returns.
            inner.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await inner
            await asyncio.Event().wait()

        return run()

    monkeypatch.setattr(ControlShell, "run", gated_run)
    notifier = RecordingNotifier()
    clock = LoopClock()
    async with FakeRig(tmp_path, clock=clock, links="memory") as rig:
        daemon = Daemon(
            parse_settings(rig.config_doc(api_port=0, control={"mode": "hold"})),
            env=rig.env,
            notifier=notifier,
            clock=clock,
        )
        task = asyncio.create_task(daemon.run())
        try:
            async with ClientSession() as session:

                async def healthz() -> int:
                    async with session.get(f"http://127.0.0.1:{daemon.api_port}/healthz") as resp:
                        return resp.status

                async def ready() -> bool:
                    return "ready" in notifier.calls and daemon.api_port is not None

                await until(ready, "READY", 10.0, poll_s=0.05)
                # Devices are up, but the control loop has not ticked: no pet, /healthz 503.
                await until(
                    lambda: daemon.state.health_now()["robot"].connected,
                    "the robot connected",
                    10.0,
                )
                await _pet_periods(daemon)
                assert notifier.pets == 0
                assert await healthz() == 503

                release.set()
                await until(lambda: notifier.pets >= 2, "watchdog pets once ticking", 10.0)
                assert await healthz() == 200

                wedge.set()

                async def unhealthy() -> bool:
                    return await healthz() == 503

                await until(unhealthy, "/healthz 503 after the loop wedged", 10.0, poll_s=0.05)
                pets = notifier.pets
                # Nothing else pets: a few pet periods later, still none.
                await _pet_periods(daemon)
                assert notifier.pets == pets
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
    assert notifier.calls[-1] == "stopping"


async def _pet_periods(daemon: Daemon, periods: int = 3) -> None:
    """Let `periods` watchdog-pet periods pass (to show that no pet came in them).

    Waiting out a span is the only way to see an absence; the one caller runs on virtual
    time, so the span costs no wall time.
    """
    await asyncio.sleep(daemon.clock.to_real(periods * WATCHDOG_PET_S))  # virtual: see above


# --- resources and scheduling ----------------------------------------------------------


def test_descriptor_limit_leaves_room_for_the_api_cap_and_the_devices() -> None:
    from relayd.api.guard import FD_RESERVE, MAX_CONNECTIONS

    # Without LimitNOFILE the soft limit is 1024; the API guard copes with that too
    # (tests/api/test_flood.py), but the unit gives the cap and the reserve ample room.
    limit = int(_service("LimitNOFILE"))
    assert limit >= 4 * (MAX_CONNECTIONS + FD_RESERVE)


def test_control_path_runs_real_time_but_children_do_not() -> None:
    from bench.latency import RT_PRIORITY

    # The priority bench/latency.py measured (bench/RESULTS.md), above normal processes
    # and below the kernel's IRQ threads; RestrictRealtime keeps relayd from raising it.
    assert _service("CPUSchedulingPolicy") == "fifo"
    assert int(_service("CPUSchedulingPriority")) == RT_PRIORITY < 50
    assert _service("CPUSchedulingResetOnFork") == "yes"
    assert _service("RestrictRealtime") == "yes"
