"""Every HTTP endpoint against a real in-process `Daemon` driving a `FakeRig`.

tests/api/test_app.py checks the app's parsing and status codes on a hand-made state; this
file checks what only the whole daemon can show: /status and /metrics carry the values
the fakes produce (the leader's bearing and RSSI from a real servo sweep, RSSI^b from the
fake airOS radio, the fake robot's pose and battery, device counters after injected
faults), /healthz follows the control loop, and the control endpoints really move the
fake robot (the VEL/RVEL commands it receives) or refuse to.

One daemon serves the module; it starts in hold mode so the robot stands still and the
world's expectations (true bearing, path loss) can be computed from the rig at any
time. Tests that change the mode put it back. The module runs in virtual time
(`relayd.runtime.vtime`): the rig's robot and servo controller are on memory links, the API
and the airOS fakes on real loopback sockets, and the seconds of scans, SIPs and
dead-man waits cost no wall time.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import pytest
import pytest_asyncio
from aiohttp import ClientSession
from prometheus_client.parser import text_string_to_metric_families

from drivers.arcos.codec import Command
from drivers.arcos.sip import wheel_to_vel_rvel
from relayd import __version__
from relayd.config.load import parse_settings
from relayd.core.vocab import Mode
from relayd.daemon import Daemon
from relayd.fakes.rig import API_TOKEN_ENV, FakeRig
from relayd.runtime.vtime import LoopClock
from tests.support import running as run_daemon

pytestmark = [pytest.mark.asyncio(loop_scope="module"), pytest.mark.virtual_time]

#: The /status fields every client may rely on.
SPEC_FIELDS = {
    "mode",
    "state",
    "reason",
    "bearing_deg",
    "rssi_leader_dbm",
    "rssi_behind_dbm",
    "situation",
    "wheels_mm_s",
    "pose",
    "battery_v",
    "sonar_mm",
    "last_scan",
    "links",
    "health",
    "uptime_s",
    "version",
}
DEVICES = {"robot", "pantilt", "wifi", "ap.rear", "ap.front"}
#: Virtual seconds: a first scan takes a few.
FIRST_SCAN_TIMEOUT_S = 30.0
DISPLAY_NAME = "relay 1 (east stairs)"
T = TypeVar("T")


@dataclass
class Relay:
    rig: FakeRig
    daemon: Daemon
    session: ClientSession
    base: str
    token: str

    async def get(self, path: str) -> tuple[int, Any]:
        async with self.session.get(self.base + path) as resp:
            text = await resp.text()
            return resp.status, json.loads(
                text
            ) if resp.content_type == "application/json" else text

    async def status(self) -> dict[str, Any]:
        code, doc = await self.get("/status")
        assert code == 200
        assert isinstance(doc, dict)
        return doc

    async def metrics(self) -> dict[tuple[str, frozenset[tuple[str, str]]], float]:
        """Every sample of /metrics keyed by (sample name, labels)."""
        async with self.session.get(self.base + "/metrics") as resp:
            assert resp.status == 200
            assert resp.headers["Content-Type"].startswith("text/plain")
            text = await resp.text()
        return {
            (s.name, frozenset(s.labels.items())): s.value
            for fam in text_string_to_metric_families(text)
            for s in fam.samples
        }

    async def post(
        self, path: str, body: Any, token: str | None = ""
    ) -> tuple[int, dict[str, Any]]:
        """POST JSON (`body` str = raw text); token "" = the right one, None = no header."""
        headers = {"Content-Type": "application/json"}
        if token is not None:
            headers["Authorization"] = f"Bearer {token or self.token}"
        data = body if isinstance(body, str) else json.dumps(body)
        async with self.session.post(self.base + path, data=data, headers=headers) as resp:
            doc = await resp.json()
            assert isinstance(doc, dict)
            return resp.status, doc


async def until(
    probe: Callable[[], Awaitable[T | None]],
    what: str,
    timeout_s: float = 10.0,
    every_s: float = 0.05,
) -> T:
    """Poll `probe` until it returns something other than None/False."""
    try:
        async with asyncio.timeout(timeout_s):
            while True:
                value = await probe()
                if value is not None and value is not False:
                    return value
                await asyncio.sleep(every_s)
    except TimeoutError:
        raise AssertionError(f"timed out after {timeout_s} s waiting for {what}") from None


@contextlib.asynccontextmanager
async def running(work: Path, *, with_token: bool = True, **config: Any) -> AsyncIterator[Relay]:
    """A FakeRig and a Daemon driving it, API on an ephemeral 127.0.0.1 port.

    `with_token=False` leaves the API token's variable out of the daemon's environment.
    """
    clock = LoopClock()
    async with FakeRig(work, clock=clock, links="memory") as rig:
        env = rig.env if with_token else {k: v for k, v in rig.env.items() if k != API_TOKEN_ENV}
        daemon = Daemon(parse_settings(rig.config_doc(api_port=0, **config)), env=env, clock=clock)
        async with run_daemon(daemon) as task:

            async def bound() -> int | None:
                if task.done():
                    task.result()  # surface a start-up failure
                return daemon.api_port

            port = await until(bound, "the API to bind")
            async with ClientSession() as session:
                yield Relay(rig, daemon, session, f"http://127.0.0.1:{port}", rig.api_token)


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def relay(tmp_path_factory: pytest.TempPathFactory) -> AsyncIterator[Relay]:
    async with running(
        tmp_path_factory.mktemp("rig"),
        control={"mode": "hold"},
        robot={"display_name": DISPLAY_NAME},
    ) as r:

        async def scanned() -> bool:
            doc = await r.status()
            return doc["last_scan"] is not None and all(
                doc["health"].get(d, {}).get("connected") for d in DEVICES
            )

        await until(scanned, "a first scan with every device up", FIRST_SCAN_TIMEOUT_S, 0.2)
        yield r


@pytest_asyncio.fixture(loop_scope="module")
async def hold(relay: Relay) -> AsyncIterator[Relay]:
    """The shared relay, put back in hold mode (robot still) after the test."""
    try:
        yield relay
    finally:
        relay.daemon.control.set_mode(Mode.HOLD)
        await until(lambda: _still(relay), "the robot to stand still again")


async def _still(relay: Relay) -> bool:
    return relay.rig.robot.vel_mm_s == 0.0 and relay.rig.robot.rvel_deg_s == 0.0


def _motion_since(relay: Relay, mark: int) -> list[tuple[int, Any]]:
    return [(c, a) for c, a in relay.rig.robot.commands[mark:] if c in (Command.VEL, Command.RVEL)]


# --- /status -----------------------------------------------------------------------------


async def test_status_carries_the_fakes_values(relay: Relay) -> None:
    rig = relay.rig
    doc = await relay.status()
    assert set(doc) >= SPEC_FIELDS
    assert doc["version"] == __version__
    assert doc["robot"] == rig.name  # from the fake robot's SYNC2 identity
    assert doc["display_name"] == DISPLAY_NAME  # from the config, robot.display_name
    assert doc["mode"] == "hold" and doc["state"] == "stopped" and doc["reason"] == "hold"
    assert doc["uptime_s"] > 0

    # The last scan is what the Yagi heard: each sample is the rig's path loss + pattern
    # at that servo angle (the procfs file holds whole dBm).
    scan = doc["last_scan"]
    assert len(scan["angles"]) == len(scan["rssi"]) == relay.daemon.settings.scan.samples
    assert min(scan["angles"]) == pytest.approx(-90, abs=1) and max(
        scan["angles"]
    ) == pytest.approx(90, abs=1)
    for angle, rssi in zip(scan["angles"], scan["rssi"], strict=True):
        assert rssi == pytest.approx(rig.rssi_dbm(angle), abs=1.0), angle
    # The bearing points at the leader; RSSI^l is the sweep's best sample.
    assert doc["bearing_deg"] == pytest.approx(rig.true_bearing_deg(), abs=5.0)
    assert scan["bearing_deg"] == pytest.approx(doc["bearing_deg"], abs=1e-3)
    assert doc["rssi_leader_dbm"] == max(scan["rssi"])
    assert doc["rssi_leader_dbm"] == pytest.approx(rig.rssi_dbm(rig.true_bearing_deg()), abs=1.0)
    assert doc["link_bearing_deg"] == pytest.approx(doc["bearing_deg"], abs=1.0)
    assert scan["age_s"] >= 0 and scan["period_s"] > 0

    # RSSI^b and the link figures come from the fake airOS radios.
    assert doc["rssi_behind_dbm"] == -55.0
    assert (
        doc["links"]["rear"]["signal_dbm"] == -55.0 and doc["links"]["front"]["signal_dbm"] == -50.0
    )
    assert doc["links"]["front"]["ccq_pct"] == 95.0 and doc["links"]["rear"]["tx_mbps"] == 54.0

    # Pose, battery and sonar come from the fake robot's SIPs.
    assert doc["pose"]["x_mm"] == pytest.approx(rig.robot.x_mm, abs=5)
    assert doc["pose"]["y_mm"] == pytest.approx(rig.robot.y_mm, abs=5)
    assert doc["battery_v"] == pytest.approx(rig.robot.battery_v, abs=0.1)
    assert doc["motors_enabled"] is True
    assert len(doc["sonar_mm"]) == 16 and all(isinstance(r, int) for r in doc["sonar_mm"])
    assert doc["wheels_mm_s"] == {"left": 0.0, "right": 0.0} and doc["situation"] == 0

    assert set(doc["health"]) == DEVICES
    for name, health in doc["health"].items():
        assert health["connected"] is True, name
        assert health["errors"] == 0 and health["last_error"] is None, name
    for name in ("robot", "pantilt", "wifi", "ap.rear", "ap.front"):
        assert 0 <= doc["health"][name]["age_s"] < 5.0, name
    assert doc["thresholds"]["threshold_l_dbm"] == relay.daemon.settings.control.threshold_l_dbm

    # Live, not cached: a new RSSI^b from the rear radio shows up.
    try:
        rig.set_rear_signal(-63.0)

        async def behind() -> bool:
            return (await relay.status())["rssi_behind_dbm"] == -63.0

        await until(behind, "RSSI^b -63 dBm in /status")
    finally:
        rig.set_rear_signal(-55.0)
    uptime = doc["uptime_s"]
    assert (await relay.status())["uptime_s"] > uptime


async def test_status_never_contains_a_secret(relay: Relay) -> None:
    text = json.dumps(await relay.status())
    assert relay.token not in text and relay.rig.ap_password not in text


# --- /healthz ----------------------------------------------------------------------------


async def test_healthz_ok_while_the_loop_ticks(relay: Relay) -> None:
    ticks = set()
    for _ in range(4):
        code, doc = await relay.get("/healthz")
        assert code == 200, doc
        assert doc["ok"] is True and doc["mode"] == "hold"
        assert 0 <= doc["loop_age_s"] <= doc["max_age_s"]
        ticks.add(relay.daemon.state.loop_tick_t)
        await asyncio.sleep(0.15)
    assert len(ticks) > 1  # the loop really ticked between the calls


# --- /metrics ----------------------------------------------------------------------------


def _one(
    samples: dict[tuple[str, frozenset[tuple[str, str]]], float], name: str, **labels: str
) -> float:
    return samples[(name, frozenset(labels.items()))]


async def test_metrics_carry_the_run(relay: Relay) -> None:
    async def consistent() -> tuple[dict[str, Any], Any] | None:
        # Scrape between two /status reads of the same scan so levels can be compared.
        before = await relay.status()
        samples = await relay.metrics()
        after = await relay.status()
        return (after, samples) if before["scan_count"] == after["scan_count"] else None

    doc, m = await until(consistent, "a scrape that no scan interrupted")
    assert _one(m, "relayd_build_info", version=__version__) == 1.0
    assert _one(m, "relayd_mode", relayd_mode="hold") == 1.0
    assert _one(m, "relayd_bearing_degrees", antenna="scan") == pytest.approx(doc["bearing_deg"])
    assert _one(m, "relayd_bearing_degrees", antenna="link") == pytest.approx(
        doc["link_bearing_deg"]
    )
    assert _one(m, "relayd_rssi_dbm", peer="leader") == doc["rssi_leader_dbm"]
    assert _one(m, "relayd_rssi_dbm", peer="behind") == -55.0
    assert (
        _one(m, "relayd_rssi_threshold_dbm", peer="leader") == doc["thresholds"]["threshold_l_dbm"]
    )
    assert _one(m, "relayd_wheel_speed_meters_per_second", wheel="left") == 0.0
    assert _one(m, "relayd_battery_volts") == pytest.approx(relay.rig.robot.battery_v, abs=0.1)
    assert _one(m, "relayd_scans_total") == doc["scan_count"] >= 1
    # Every finished scan with a measured period went into the histogram.
    periods = _one(m, "relayd_scan_period_seconds_count")
    assert doc["scan_count"] - 1 <= periods <= doc["scan_count"] and periods >= 1
    mean_period = _one(m, "relayd_scan_period_seconds_sum") / periods
    assert 0.5 < mean_period < 20.0
    for name in DEVICES:
        assert _one(m, "relayd_device_connected", device=name) == 1.0, name
        assert _one(m, "relayd_device_errors_total", device=name) == 0.0, name

    # SIPs arrive at the fake's 10 Hz and each one runs the controller (step histogram).
    t0 = asyncio.get_running_loop().time()
    sips0 = _one(m, "relayd_sips_received_total")
    step0 = _one(m, "relayd_control_step_seconds_count")
    await asyncio.sleep(1.0)
    m2 = await relay.metrics()
    rate = (_one(m2, "relayd_sips_received_total") - sips0) / (
        asyncio.get_running_loop().time() - t0
    )
    assert 4.0 < rate < 15.0, rate
    assert _one(m2, "relayd_control_step_seconds_count") - step0 >= rate * 0.5
    assert _one(m2, "relayd_control_step_seconds_bucket", le="+Inf") == _one(
        m2, "relayd_control_step_seconds_count"
    )


async def test_device_errors_and_reconnects_come_from_the_run(relay: Relay) -> None:
    rig = relay.rig
    m = await relay.metrics()
    reconnects0 = _one(m, "relayd_device_reconnects_total", device="ap.rear")
    errors0 = _one(m, "relayd_device_errors_total", device="ap.front")

    # The rear radio forgets its session: the poller logs in again (a reconnect).
    rig.rear.expire_sessions()
    # The front radio answers garbage for a while: errors.
    rig.front.malformed = True
    try:

        async def faults_seen() -> dict[Any, float] | None:
            s = await relay.metrics()
            return (
                s
                if (
                    _one(s, "relayd_device_reconnects_total", device="ap.rear") > reconnects0
                    and _one(s, "relayd_device_errors_total", device="ap.front") > errors0
                )
                else None
            )

        m = await until(faults_seen, "ap.rear reconnect and ap.front errors in /metrics")
    finally:
        rig.front.malformed = False
    doc = await relay.status()
    assert doc["health"]["ap.rear"]["reconnects"] >= _one(
        m, "relayd_device_reconnects_total", device="ap.rear"
    )
    assert doc["health"]["ap.front"]["errors"] >= 1
    assert _one(m, "relayd_device_errors_total", device="robot") == 0.0

    async def front_back() -> bool:
        return (await relay.status())["health"]["ap.front"]["connected"] is True

    await until(front_back, "ap.front connected again", 15.0)


# --- /openapi.json -----------------------------------------------------------------------


async def test_openapi_describes_the_daemons_routes(relay: Relay) -> None:
    code, doc = await relay.get("/openapi.json")
    assert code == 200 and doc["openapi"].startswith("3.")
    assert {"/status", "/healthz", "/metrics", "/api/mode", "/api/drive", "/"} <= set(doc["paths"])
    # Every field the daemon's /status actually has is declared (a status schema that
    # lags behind the daemon would make clients drop data).
    status_schema = doc["components"]["schemas"]["Status"]
    assert set((await relay.status()).keys()) <= set(status_schema["properties"])


# --- control endpoints -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("path", "body"),
    [("/api/mode", {"mode": "manual"}), ("/api/drive", {"left_mm_s": 300, "right_mm_s": 300})],
)
@pytest.mark.parametrize("token", [None, "wrong-token"])
async def test_control_without_the_right_token_is_401(
    relay: Relay, path: str, body: dict[str, Any], token: str | None
) -> None:
    mark = len(relay.rig.robot.commands)
    code, doc = await relay.post(path, body, token=token)
    assert code == 401 and doc["error"]
    assert relay.daemon.state.mode is Mode.HOLD
    assert relay.token not in json.dumps(doc)
    assert all(arg == 0 for _, arg in _motion_since(relay, mark))


@pytest.mark.parametrize(
    ("path", "body", "field"),
    [
        ("/api/mode", {"mode": "sideways"}, "mode"),
        ("/api/mode", {}, "mode"),
        ("/api/drive", {"left_mm_s": 100}, "right_mm_s"),
        ("/api/drive", {"left_mm_s": "fast", "right_mm_s": 0}, "left_mm_s"),
        ("/api/drive", {"left_mm_s": 0, "right_mm_s": 99999}, "right_mm_s"),
        ("/api/drive", "{not json", None),
    ],
)
async def test_bad_input_is_400_naming_the_field(
    hold: Relay, path: str, body: Any, field: str | None
) -> None:
    relay = hold
    relay.daemon.control.set_mode(Mode.MANUAL)  # so a valid drive would have been accepted
    mark = len(relay.rig.robot.commands)
    code, doc = await relay.post(path, body)
    assert code == 400 and doc["field"] == field and doc["error"]
    assert relay.daemon.state.mode is Mode.MANUAL
    assert all(arg == 0 for _, arg in _motion_since(relay, mark))


async def test_drive_outside_manual_is_409_and_the_robot_stays(hold: Relay) -> None:
    relay = hold
    for mode in ("hold", "follow"):
        code, doc = await relay.post("/api/mode", {"mode": mode})
        assert code == 200 and doc == {"ok": True, "mode": mode}
        mark = len(relay.rig.robot.commands)
        code, doc = await relay.post("/api/drive", {"left_mm_s": -300, "right_mm_s": -300})
        assert code == 409 and doc["mode"] == mode
        # Follow mode drives forward on its own; the refused command must not reverse it.
        assert not any(arg < 0 for c, arg in _motion_since(relay, mark) if c == Command.VEL)
        code, doc = await relay.post("/api/mode", {"mode": "hold"})
        assert code == 200


async def test_follow_mode_set_over_the_api_drives_to_the_leader(hold: Relay) -> None:
    relay = hold
    start = relay.rig.leader_distance_m()
    code, _ = await relay.post("/api/mode", {"mode": "follow"})
    assert code == 200

    async def closer() -> bool:
        return relay.rig.leader_distance_m() < start - 0.05

    await until(closer, "the robot to close in on the leader")
    doc = await relay.status()
    assert doc["mode"] == "follow" and doc["state"] == "driving"
    assert doc["wheels_mm_s"]["left"] > 0 and doc["wheels_mm_s"]["right"] > 0

    # Driving, SIPs change the wheel command: each change is a control-latency sample,
    # SIP bytes in to VEL/RVEL written, well under a second even on a loaded machine.
    # (The first command after the mode change is the operator's, not a SIP's: wait for
    # a SIP-caused one.)
    async def sampled() -> dict[tuple[str, frozenset[tuple[str, str]]], float] | None:
        m = await relay.metrics()
        return m if _one(m, "relayd_control_latency_seconds_count") >= 1 else None

    m = await until(sampled, "a SIP-caused wheel command")
    count = _one(m, "relayd_control_latency_seconds_count")
    assert count >= 1
    assert _one(m, "relayd_control_latency_seconds_bucket", le="+Inf") == count
    assert _one(m, "relayd_control_latency_seconds_sum") / count < 0.1


async def test_manual_drive_moves_the_fake_robot(hold: Relay) -> None:
    relay = hold
    robot = relay.rig.robot
    code, doc = await relay.post("/api/mode", {"mode": "manual"})
    assert code == 200 and doc["mode"] == "manual"
    v_max = relay.daemon.settings.control.v_max_mm_s
    x0 = robot.x_mm

    async def drive_until(left: float, right: float, want: tuple[int, int], what: str) -> None:
        """Keep commanding (inside the dead-man time) until the robot got VEL/RVEL `want`."""
        mark = len(robot.commands)

        async def got() -> bool:
            code, doc = await relay.post("/api/drive", {"left_mm_s": left, "right_mm_s": right})
            assert code == 200 and doc == {"ok": True, "left_mm_s": left, "right_mm_s": right}
            motion = _motion_since(relay, mark)
            vel = [a for c, a in motion if c == Command.VEL]
            rvel = [a for c, a in motion if c == Command.RVEL]
            return bool(vel and rvel) and (vel[-1], rvel[-1]) == want

        await until(got, what, every_s=0.1)

    await drive_until(200, 200, (200, 0), "VEL 200 / RVEL 0 at the robot")

    async def moved() -> bool:
        await relay.post("/api/drive", {"left_mm_s": 200, "right_mm_s": 200})
        return robot.x_mm > x0 + 30

    await until(moved, "the fake robot to roll forward", every_s=0.1)
    doc = await relay.status()
    assert doc["state"] == "driving" and doc["reason"] == "manual"
    assert doc["wheels_mm_s"] == {"left": 200.0, "right": 200.0}
    m = await relay.metrics()
    assert _one(m, "relayd_wheel_speed_meters_per_second", wheel="left") == pytest.approx(0.2)

    # A turn is reflected as VEL + RVEL; beyond v_max each wheel is clamped.
    await drive_until(100, 300, wheel_to_vel_rvel(100, 300), "a left turn at the robot")
    await drive_until(1000, 1000, wheel_to_vel_rvel(v_max, v_max), "v_max-clamped wheels")

    # No more commands: the dead-man stops the robot.
    async def deadman() -> bool:
        doc = await relay.status()
        return doc["reason"] == "deadman" and robot.target_vel_mm_s == 0.0

    await until(deadman, "the dead-man stop")
    assert (await relay.status())["wheels_mm_s"] == {"left": 0.0, "right": 0.0}


# --- a second relay: no token configured, then a silent robot ---------------------------------


async def test_without_a_token_control_is_403_and_healthz_follows_the_loop(tmp_path: Path) -> None:
    async with running(tmp_path, with_token=False) as relay:
        assert relay.daemon.settings.api.token_env == API_TOKEN_ENV  # configured, but unset
        mark = len(relay.rig.robot.commands)
        for path, body in (
            ("/api/mode", {"mode": "manual"}),
            ("/api/drive", {"left_mm_s": 100, "right_mm_s": 100}),
        ):
            for token in (None, "", "anything"):
                code, doc = await relay.post(path, body, token=token)
                assert code == 403 and "disabled" in doc["error"], (path, token)
        assert relay.daemon.state.mode is Mode.FOLLOW
        assert all(arg == 0 for _, arg in _motion_since(relay, mark))

        async def healthy() -> dict[str, Any] | None:
            code, doc = await relay.get("/healthz")
            return doc if code == 200 else None

        await until(healthy, "/healthz 200")
        # A robot that stops talking is a fault in /status, but the loop still ticks
        # (it is what stops the wheels), so the process stays healthy for systemd.
        relay.rig.robot.silent = True

        async def fault() -> bool:
            return (await relay.status())["state"] == "fault"

        await until(fault, "state fault after the robot went silent")
        code, doc = await relay.get("/healthz")
        assert code == 200 and doc["ok"] is True and doc["state"] == "fault"
