"""sd_notify over real datagram sockets, and the systemd unit and udev rules shipped with relayd."""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from relayd.runtime.sdnotify import SdNotifier
from tests.support import parse_unit, skip_or_fail

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def path_socket(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = str(tmp_path / "notify.sock")
    sock.bind(path)
    sock.settimeout(2.0)
    yield sock, path
    sock.close()


@pytest.fixture
def abstract_socket() -> Iterator[tuple[socket.socket, str]]:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    name = f"relayd-test-{uuid.uuid4().hex}"
    sock.bind("\0" + name)
    sock.settimeout(2.0)
    yield sock, "@" + name
    sock.close()


def test_path_socket_receives_one_datagram_per_call(path_socket: tuple[socket.socket, str]) -> None:
    sock, path = path_socket
    n = SdNotifier({"NOTIFY_SOCKET": path})
    assert n.enabled
    n.ready()
    assert sock.recv(4096) == b"READY=1\nSTATUS=running"
    n.status("base: reconnecting\nsecond line")
    assert sock.recv(4096) == b"STATUS=base: reconnecting second line"
    n.stopping()
    assert sock.recv(4096) == b"STOPPING=1\nSTATUS=stopping"
    n.close()


def test_abstract_socket(abstract_socket: tuple[socket.socket, str]) -> None:
    sock, name = abstract_socket
    n = SdNotifier({"NOTIFY_SOCKET": name, "WATCHDOG_USEC": "5000000"}, pid=1234)
    assert n.enabled and n.watchdog_interval_s == 2.5
    n.watchdog()
    assert sock.recv(4096) == b"WATCHDOG=1"
    n.close()


def test_disabled_outside_systemd(path_socket: tuple[socket.socket, str]) -> None:
    sock, _ = path_socket
    n = SdNotifier({})
    assert not n.enabled and n.watchdog_interval_s is None
    n.ready()
    n.status("x")
    n.watchdog()
    n.stopping()
    sock.settimeout(0.05)
    with pytest.raises(TimeoutError):
        sock.recv(4096)


def test_watchdog_pid_is_respected(path_socket: tuple[socket.socket, str]) -> None:
    sock, path = path_socket
    other = SdNotifier(
        {"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "10000000", "WATCHDOG_PID": "999"}, pid=1000
    )
    assert other.watchdog_interval_s is None
    other.watchdog()  # not for us: nothing sent
    ours = SdNotifier(
        {"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "10000000", "WATCHDOG_PID": str(os.getpid())}
    )
    assert ours.watchdog_interval_s == 5.0
    ours.watchdog()
    assert sock.recv(4096) == b"WATCHDOG=1"
    for bad in ("0", "-5", "soon"):
        assert SdNotifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": bad}).watchdog_interval_s is None


def test_unreachable_socket_is_counted_not_raised(tmp_path: Path) -> None:
    n = SdNotifier({"NOTIFY_SOCKET": str(tmp_path / "gone.sock")})
    assert n.enabled
    n.ready()
    n.status("still here")
    assert n.errors == 2
    n.close()


# --- systemd unit ------------------------------------------------------------------------


def test_unit_file_directives() -> None:
    unit = parse_unit((ROOT / "systemd" / "relayd.service").read_text())
    svc = unit["Service"]

    def one(key: str) -> str:
        assert len(svc[key]) == 1, key
        return svc[key][0]

    assert one("Type") == "notify"
    assert one("NotifyAccess") == "main"
    assert one("WatchdogSec") == "5s"
    assert one("Restart") == "on-failure"
    assert one("RestartSec") == "2s"
    assert one("TimeoutStopSec") == "5s"
    assert one("User") == "relayd"
    assert "dialout" in one("SupplementaryGroups").split()
    assert one("ExecStart") == "/opt/relayd/venv/bin/relayd run -c /etc/relayd/relayd.toml"
    assert one("EnvironmentFile") == "-/etc/relayd/secrets.env"
    assert one("DevicePolicy") == "closed"
    allowed = set(svc["DeviceAllow"])
    assert {"char-ttyUSB rw", "char-ttyACM rw"} <= allowed
    assert not any("pts" in a for a in allowed)
    assert "PrivateDevices" not in svc or one("PrivateDevices") == "no"
    families = one("RestrictAddressFamilies").split()
    assert {"AF_UNIX", "AF_INET", "AF_NETLINK"} <= set(families)
    assert one("NoNewPrivileges") == "yes"
    assert one("ProtectSystem") == "strict"
    assert one("CapabilityBoundingSet") == ""
    assert "WantedBy" in unit["Install"]
    # The unit must not hold a secret itself.
    assert not any("TOKEN=" in v or "PASSWORD=" in v for values in svc.values() for v in values)


def test_unit_file_passes_systemd_analyze_verify(tmp_path: Path) -> None:
    if shutil.which("systemd-analyze") is None:
        skip_or_fail("systemd-analyze not installed (apt-get install systemd)")
    # verify wants ExecStart to exist; point a copy at a real executable, keep the rest.
    text = (ROOT / "systemd" / "relayd.service").read_text()
    text = text.replace("/opt/relayd/venv/bin/relayd", shutil.which("true") or "/bin/true")
    unit = tmp_path / "relayd.service"
    unit.write_text(text)
    proc = subprocess.run(
        ["systemd-analyze", "verify", "--man=no", str(unit)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    # Outside a booted systemd (containers, CI) verify cannot talk to the manager; only
    # complaints about our own file count.
    relevant = [
        line
        for line in (proc.stdout + proc.stderr).splitlines()
        if "relayd.service" in line and "Failed to" not in line
    ]
    assert not relevant, "\n".join(relevant)


# --- udev rules --------------------------------------------------------------------------

_MATCH = re.compile(
    r'^(SUBSYSTEMS?|ATTRS?\{[a-z_A-Z]+\}|KERNELS?|ACTION|ENV\{[A-Z_]+\}|DRIVERS?)=="[^"]*"$'
)
_ASSIGN = re.compile(r'^(SYMLINK\+|NAME|GROUP|MODE|TAG\+|ENV\{[A-Z_]+\})="[^"]*"$')


def test_udev_rules_are_well_formed() -> None:
    text = (ROOT / "config" / "99-relayd.rules").read_text()
    rules = [
        line.strip()
        for line in text.splitlines()
        if line.strip() and not line.lstrip().startswith("#")
    ]
    assert rules
    symlinks, names = set(), set()
    for rule in rules:
        parts = [p.strip() for p in rule.split(",")]
        matches = [p for p in parts if _MATCH.match(p)]
        assigns = [p for p in parts if _ASSIGN.match(p)]
        assert len(matches) + len(assigns) == len(parts), f"unparsed key in: {rule}"
        assert matches and assigns, rule
        for a in assigns:
            if a.startswith("SYMLINK+="):
                symlinks.add(a.split("=", 1)[1].strip('"'))
            if a.startswith("NAME="):
                names.add(a.split("=", 1)[1].strip('"'))
    assert {"relay/base", "relay/servo"} <= symlinks
    assert names, "the Wi-Fi adapter gets a stable interface name"
    assert 'ATTRS{idVendor}=="1ffb"' in text  # Pololu Maestro
    assert "udevadm info -a -n" in text
