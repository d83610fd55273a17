"""Fault injection against a whole in-process `Daemon` driving a `FakeRig`.

Each test starts the real daemon on the rig's fakes (robot and servo controller on
ptys, RSSI file, airOS radios on loopback), lets it reach DRIVING towards the rig's
leader, breaks one thing and checks what a robot must do about it: the wheels go to
zero in time and say why, /status shows the fault, and everything resumes by itself
once the data is back, with no task of the daemon failing or restarting.

Timing is measured on the daemon's own control steps (every `Decision` the brain returns is
recorded with its clock time), so the figures do not depend on how fast this test
polls. Bounds carry slack for the shared two-core machine; the scan and the rear-AP
poll are configured short so the file stays fast.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from drivers.transport.link import REPLUG_POLL_S, port_missing, wait_before_retry
from relayd.config.load import load_settings, parse_settings
from relayd.core.events import Action, Decision, Event
from relayd.daemon import Daemon, control_params
from relayd.fakes.rig import FakeRig
from relayd.runtime.vtime import LoopClock
from tests.support import running as run_daemon
from tests.support import until

#: A short scan (60 deg, 5 steps: ~0.8 s) so "two scan periods" of RSSI staleness is ~1.7 s.
FAST_SCAN = {"samples": 5, "width_deg": 60.0}
#: Rear AP polled every 0.2 s: RSSI^b is stale after 3 polls (0.6 s).
FAST_AP = {"rear": {"poll_s": 0.2, "timeout_s": 0.5}, "front": {"poll_s": 0.5}}
SIP_PERIOD_S = 0.1
#: Scheduling slack on a loaded shared machine.
SLACK_S = 0.15
START_TIMEOUT_S = 30.0


@dataclass
class Step:
    t: float
    reason: str
    left: float
    right: float


@dataclass
class Run:
    rig: FakeRig
    daemon: Daemon
    task: asyncio.Task[None]
    session: aiohttp.ClientSession
    steps: list[Step] = field(default_factory=list)
    #: Clock time the scan servo stopped answering (set by the servo faults below).
    servo_broken_t: float | None = None

    @property
    def base(self) -> str:
        return f"http://127.0.0.1:{self.daemon.api_port}"

    async def status(self) -> dict[str, Any]:
        async with self.session.get(self.base + "/status") as resp:
            assert resp.status == 200
            doc = await resp.json()
            assert isinstance(doc, dict)
            return doc

    def now(self) -> float:
        return self.daemon.clock.now()

    def first_step(self, since: float, pred: Callable[[Step], bool]) -> Step | None:
        return next((s for s in self.steps if s.t >= since and pred(s)), None)

    def assert_alive(self) -> None:
        """The daemon runs and none of its supervised tasks ever failed or restarted."""
        assert not self.task.done(), self.task
        sup = self.daemon.supervisor
        assert {n: sup.restarts(n) for n in sup.names} == dict.fromkeys(sup.names, 0)


def zero(s: Step) -> bool:
    return s.left == 0.0 and s.right == 0.0


@contextlib.asynccontextmanager
async def running(
    work: Path,
    *,
    wrong_ap_password: bool = False,
    drive: bool = True,
    virtual: bool = False,
    **config: Any,
) -> AsyncIterator[Run]:
    """A FakeRig and a Daemon on it (API on port 0); waits until the robot drives.

    `wrong_ap_password`: the config is written as `relayd run` reads it, secrets in
    files, and the AP password file then holds a wrong password. `virtual`: the base
    and the servo controller on in-memory links and the loop's (virtual) clock, for a
    test marked `virtual_time`; otherwise ptys and the real clock.
    """
    rig = FakeRig(work, clock=LoopClock(), links="memory") if virtual else FakeRig(work)
    async with rig, aiohttp.ClientSession() as session:
        config.setdefault("scan", FAST_SCAN)
        config.setdefault("ap", FAST_AP)
        if wrong_ap_password:
            path = rig.write_config(secrets_in_files=True, **config)
            pw_file = load_settings(path).ap.rear.password_file  # type: ignore[union-attr]
            assert pw_file is not None
            Path(pw_file).write_text("not-" + rig.ap_password + "\n", encoding="utf-8")
            settings = load_settings(path)
            env: dict[str, str] = {}
        else:
            settings = parse_settings(rig.config_doc(**config))
            env = rig.env
        daemon = Daemon(settings, env=env, clock=rig.clock)
        steps: list[Step] = []
        on_actions = daemon._on_actions

        def record(event: Event, actions: Sequence[Action]) -> None:
            for a in actions:
                if isinstance(a, Decision):
                    steps.append(Step(a.t, a.reason, a.left_mm_s, a.right_mm_s))
            on_actions(event, actions)

        daemon.bus.connect(daemon.brain.handle, record)
        async with run_daemon(daemon) as task:
            run = Run(rig, daemon, task, session, steps)
            await until(
                lambda: daemon.api_port is not None or task.done(), "the API", START_TIMEOUT_S
            )
            if drive:
                await until(
                    lambda: daemon.state.reason == "driving" or task.done(),
                    "driving",
                    START_TIMEOUT_S,
                )
            assert not task.done(), task
            yield run


# ---------------------------------------------------------------- the robot's port vanishes

#: Away until the reconnect backoff has grown past a second: its delays are 0.2, 0.4, 0.8,
#: then 1.6 s, so the fourth delay is being waited out.
AWAY_BACKOFF_ATTEMPTS = 4
RECONNECT_WITHIN_S = 1.0


async def test_robot_port_vanishes_and_returns(tmp_path: Path) -> None:
    async with running(tmp_path) as run:
        daemon, rig = run.daemon, run.rig
        robot = daemon.robot
        assert robot.connected and daemon.state.wheels_left_mm_s != 0.0
        t_hang = run.now()
        rig.robot.hang_up()
        await until(
            lambda: daemon.state.wheels_left_mm_s == 0.0 and daemon.state.reason == "no_sip",
            "wheels zero after the hang-up",
            5.0,
        )
        stop = run.first_step(t_hang, zero)
        assert stop is not None and stop.reason == "no_sip"
        # At once: the link's loss is seen, not only the SIP timeout (0.5 s) later.
        assert stop.t - t_hang < SIP_PERIOD_S + SLACK_S + 0.1, stop.t - t_hang
        assert daemon.state.wheels_right_mm_s == 0.0
        assert str(daemon.state.state) == "fault"

        async def fault_shown() -> bool:
            doc = await run.status()
            h = doc["health"]["robot"]
            return (
                not h["connected"]
                and h["last_error"] is not None
                and doc["state"] == "fault"
                and doc["wheels_mm_s"] == {"left": 0.0, "right": 0.0}
            )

        await until(fault_shown, "/status showing the robot fault", 5.0, poll_s=0.05)
        doc = await run.status()
        assert port_missing(str(rig.robot_port))
        assert str(rig.robot_port) in doc["health"]["robot"]["last_error"]

        await until(
            lambda: robot.backoff.attempts >= AWAY_BACKOFF_ATTEMPTS,
            "the reconnect backoff grown past a second",
            10.0,
        )
        assert not robot.connected
        # Nothing moved while away: zero was the last wheel command, and stays.
        assert all(zero(s) for s in run.steps if s.t >= stop.t)

        t_back = time.monotonic()
        rig.robot.reappear()
        await until(lambda: robot.connected, "the robot reconnecting", 10.0)
        t_conn = time.monotonic()
        assert t_conn - t_back < RECONNECT_WITHIN_S + 0.2, (
            f"reconnected {t_conn - t_back:.2f} s after return"
        )
        await until(lambda: daemon.state.reason == "driving", "driving again", 10.0)

        async def recovery_shown() -> bool:
            doc = await run.status()
            h = doc["health"]["robot"]
            return h["connected"] and h["reconnects"] >= 1 and doc["state"] == "driving"

        await until(recovery_shown, "/status showing the recovery", 5.0, poll_s=0.05)
        run.assert_alive()


async def status_until(
    run: Run, pred: Callable[[dict[str, Any]], bool], what: str, timeout_s: float = 5.0
) -> dict[str, Any]:
    """GET /status until `pred` holds (a driver notices a failure a moment after it happens)."""

    async def holds() -> dict[str, Any] | None:
        doc = await run.status()
        return doc if pred(doc) else None

    doc: dict[str, Any] = await until(holds, what, timeout_s, poll_s=0.05)
    return doc


@pytest.mark.virtual_time
async def test_replugged_port_is_retried_at_once_not_after_the_backoff(tmp_path: Path) -> None:
    """The fix under the reconnect bound: the wait ends when the path reappears.

    On virtual time: the 30 s backoff is waited out for real (in no wall time), so what
    does not end early is seen not to, to the end of the backoff.
    """
    clock = LoopClock()
    path = tmp_path / "ttyUSB9"
    stop = asyncio.Event()
    waiter = asyncio.create_task(wait_before_retry(str(path), 30.0, clock, stop))
    await asyncio.sleep(20.0)  # virtual: two thirds of the backoff, the port still missing
    assert not waiter.done()
    path.touch()
    t0 = clock.now()
    await waiter
    assert clock.now() - t0 <= REPLUG_POLL_S + 1e-9  # at the next look for the path
    # A port that is there but failing waits the whole backoff...
    t0 = clock.now()
    await wait_before_retry(str(path), 30.0, clock, stop)
    assert clock.now() - t0 == pytest.approx(30.0)
    # ...unless told to stop.
    waiter = asyncio.create_task(wait_before_retry(str(path), 30.0, clock, stop))
    await asyncio.sleep(20.0)  # virtual
    assert not waiter.done()
    t0 = clock.now()
    stop.set()
    await waiter
    assert clock.now() == t0
    assert not port_missing("socket://127.0.0.1:1")


# ---------------------------------------------------------------- each source goes stale


@dataclass
class Source:
    name: str
    reason: str
    threshold_s: Callable[[Daemon], float]
    #: Clock time of the newest datum from this source (read after the wheels stopped).
    data_t: Callable[[Run], float | None]
    break_: Callable[[Run], Any]
    mend: Callable[[Run], Any]


def _last_sip_t(run: Run) -> float | None:
    sip = run.daemon.robot.last_sip
    return None if sip is None else float(sip.t)


def _rear_t(run: Run) -> float | None:
    link = run.daemon.state.links.get("rear")
    return None if link is None else link.t


def _servo_t(run: Run) -> float | None:
    return run.servo_broken_t


async def _servo_silent(run: Run) -> None:
    # The first request left unanswered marks the threshold: the controller hung then.
    pt = run.daemon.pantilt
    before = pt.counters["timeouts"]
    run.rig.maestro.silent = True
    await until(lambda: pt.counters["timeouts"] > before, "a servo reply timeout", 10.0)
    # The timeout fired reply_timeout_s after the request went out and was noted at once.
    run.servo_broken_t = run.now()


def _servo_hang_up(run: Run) -> None:
    run.servo_broken_t = run.now()
    run.rig.maestro.hang_up()


SOURCES = [
    Source(
        "sip",
        "no_sip",
        lambda d: d.settings.robot.lost_after_s,
        _last_sip_t,
        lambda r: setattr(r.rig.robot, "silent", True),
        lambda r: setattr(r.rig.robot, "silent", False),
    ),
    Source(
        "rssi",
        "rssi_stale",
        lambda d: control_params(d.settings).rssi_timeout_s,
        lambda r: r.daemon.monitor.last_fresh_t if r.daemon.monitor else None,
        lambda r: setattr(r.rig, "rssi_frozen", True),
        lambda r: setattr(r.rig, "rssi_frozen", False),
    ),
    Source(
        "servo_hang_up",
        "scan_servo",
        lambda d: 0.0,
        _servo_t,
        _servo_hang_up,
        lambda r: r.rig.maestro.reappear(),
    ),
    Source(
        "servo_silent",
        "scan_servo",
        lambda d: 0.0,
        _servo_t,
        _servo_silent,
        lambda r: setattr(r.rig.maestro, "silent", False),
    ),
    Source(
        "rear_ap",
        "rear_link_stale",
        lambda d: control_params(d.settings).rear_timeout_s,
        _rear_t,
        lambda r: r.rig.rear.set_down(True),
        lambda r: r.rig.rear.set_down(False),
    ),
]


async def _maybe_await(value: Any) -> None:
    if asyncio.iscoroutine(value):
        await value


@pytest.mark.virtual_time
async def test_each_data_source_goes_stale_in_turn(tmp_path: Path) -> None:
    """SIP, RSSI, scan servo (pulled and hung), rear AP: stop within a SIP period of the threshold."""
    async with running(tmp_path, virtual=True, control={"rear_link": "require"}) as run:
        daemon = run.daemon
        healthy_since = run.now()
        for src in SOURCES:
            # Healthy again: driving, on a scan finished since the last repair (a servo
            # that came back resumes on its old bearing until its first sweep ends, and
            # a fault then would meet the "no completed scan" rule first).
            await until(
                lambda: (
                    daemon.state.reason == "driving"
                    and daemon.state.last_scan is not None
                    and daemon.state.last_scan.t >= healthy_since  # noqa: B023
                ),
                f"driving before {src.name}",
                15.0,
            )
            t_break = run.now()
            await _maybe_await(src.break_(run))
            reason = src.reason
            await until(lambda: daemon.state.reason == reason, f"reason {reason}", 10.0)  # noqa: B023
            stop = run.first_step(t_break, zero)
            assert stop is not None
            assert stop.reason == src.reason, (src.name, stop)
            data_t = src.data_t(run)
            assert data_t is not None
            threshold = src.threshold_s(daemon)
            age = stop.t - data_t
            # Not before the data was really stale, and at most one SIP period after.
            assert age >= threshold - 0.01 or src.name.startswith("servo"), (
                src.name,
                age,
                threshold,
            )
            assert age <= threshold + SIP_PERIOD_S + SLACK_S, (src.name, age, threshold)
            assert daemon.state.wheels_left_mm_s == daemon.state.wheels_right_mm_s == 0.0
            assert str(daemon.state.state) == "fault"
            # A hung servo controller still takes writes: hold long enough for the scanner
            # to have retried its sweep more than once.
            await asyncio.sleep(1.0 if src.name.startswith("servo") else 0.3)
            # Still held: no wheel command between the stop and the repair.
            assert all(zero(s) for s in run.steps if s.t >= stop.t), src.name
            assert daemon.state.reason == src.reason
            if src.name == "rear_ap":
                # /status does not go on showing an RSSI^b the controller refuses.
                await until(lambda: daemon.state.rssi_behind_dbm is None, "RSSI^b cleared", 2.0)
                assert (await run.status())["rssi_behind_dbm"] is None
            t_mend = healthy_since = run.now()
            await _maybe_await(src.mend(run))
            await until(lambda: daemon.state.reason == "driving", f"driving after {src.name}", 15.0)
            resumed = run.first_step(t_mend, lambda s: not zero(s))
            assert resumed is not None and resumed.reason == "driving"
        run.assert_alive()


# ---------------------------------------------------------------- airOS at daemon level


@pytest.mark.virtual_time
async def test_airos_expiry_slowness_and_garbage_keep_the_daemon_right(tmp_path: Path) -> None:
    async with running(tmp_path, virtual=True, control={"rear_link": "require"}) as run:
        daemon, rig = run.daemon, run.rig
        poller = daemon.pollers["rear"]
        timeout_s = daemon.settings.ap.rear.timeout_s  # type: ignore[union-attr]

        # Session expiry: the poller logs in again at once; RSSI^b never goes stale.
        relogins = poller.counters["relogins"]
        t0 = run.now()
        rig.rear.expire_sessions()
        await until(lambda: poller.counters["relogins"] > relogins, "a re-login", 5.0)
        await asyncio.sleep(0.5)
        assert poller.state == "ok"
        assert all(s.reason == "driving" for s in run.steps if s.t >= t0)
        assert daemon.state.rssi_behind_dbm == -55.0

        # Slow answers (beyond the poll timeout): unreachable, RSSI^b stale, wheels held.
        t0 = run.now()
        rig.rear.slow_s = timeout_s * 3
        await until(
            lambda: daemon.state.reason == "rear_link_stale", "rear_link_stale on slow AP", 10.0
        )
        await until(
            lambda: poller.counters["timeouts"] > 0 and daemon.state.rssi_behind_dbm is None,
            "the timeout counted and RSSI^b cleared",
            5.0,
        )
        doc = await status_until(
            run,
            lambda d: not d["health"]["ap.rear"]["connected"],
            "/status showing the rear AP down",
        )
        rear = doc["health"]["ap.rear"]
        assert rear["errors"] >= 1 and "no answer within" in rear["last_error"]
        assert doc["rssi_behind_dbm"] is None and doc["wheels_mm_s"] == {"left": 0.0, "right": 0.0}
        rig.rear.slow_s = 0.0
        await until(lambda: daemon.state.reason == "driving", "driving after the slow AP", 15.0)
        assert poller.state == "ok" and daemon.state.rssi_behind_dbm == -55.0

        # Malformed JSON: bad_data reported, RSSI^b stale, then back after the repair.
        bad = poller.counters["bad_json"]
        rig.rear.malformed = True
        await until(lambda: poller.counters["bad_json"] > bad, "malformed JSON counted", 5.0)
        await until(
            lambda: daemon.state.reason == "rear_link_stale", "rear_link_stale on bad JSON", 10.0
        )
        doc = await status_until(
            run,
            lambda d: not d["health"]["ap.rear"]["connected"],
            "/status showing bad data from the rear AP",
        )
        assert "JSON" in doc["health"]["ap.rear"]["last_error"]
        rig.rear.malformed = False
        await until(lambda: daemon.state.reason == "driving", "driving after bad JSON", 15.0)
        doc = await status_until(
            run,
            lambda d: (
                d["health"]["ap.rear"]["connected"] and d["health"]["ap.rear"]["last_error"] is None
            ),
            "/status showing the rear AP back",
        )
        assert doc["rssi_behind_dbm"] == -55.0 and doc["links"]["rear"]["signal_dbm"] == -55.0
        # The front radio was never touched and never failed.
        assert daemon.pollers["front"].counters["errors"] == 0
        run.assert_alive()


@pytest.mark.virtual_time
async def test_wrong_ap_password_is_reported_and_holds_the_robot(tmp_path: Path) -> None:
    """A wrong password in the config's password file: auth_failed in /status, no RSSI^b."""
    async with running(
        tmp_path,
        wrong_ap_password=True,
        drive=False,
        virtual=True,
        control={"rear_link": "require"},
    ) as run:
        daemon = run.daemon
        poller = daemon.pollers["rear"]
        await until(lambda: poller.state == "auth_failed", "auth_failed", 10.0)
        await until(
            lambda: daemon.state.scan_count >= 1 and daemon.state.reason == "rear_link_stale",
            "the robot held for want of RSSI^b",
            20.0,
        )
        assert daemon.state.rssi_behind_dbm is None
        assert all(zero(s) for s in run.steps)
        status = await status_until(
            run,
            lambda d: d["health"]["ap.rear"]["last_error"] is not None,
            "/status showing the login failure",
        )
        rear = status["health"]["ap.rear"]
        assert not rear["connected"] and rear["errors"] >= 1
        assert "login refused" in rear["last_error"]
        assert status["rssi_behind_dbm"] is None and status["state"] == "fault"
        assert "rear" not in status["links"] or status["links"]["rear"]["signal_dbm"] is None
        # It does not hammer the radio: retries follow the capped backoff (1, 2, 4, 5 s).
        tries = poller.counters["auth_failures"]
        assert tries >= 1
        await asyncio.sleep(1.0)
        assert poller.counters["auth_failures"] <= tries + 1
        run.assert_alive()


async def test_shutdown_with_a_slow_ap_leaves_no_task_behind(tmp_path: Path) -> None:
    """Cancelled mid-request to a hung radio, the poller's courtesy logout must not outlive the daemon."""
    async with running(tmp_path, drive=False) as run:
        poller = run.daemon.pollers["rear"]
        await until(lambda: poller.state == "ok", "the rear AP polled", 10.0)
        rear = run.rig.rear
        requests = rear.counters["requests"]
        rear.slow_s = 2.0
        # The next request (a status poll, and later the logout) hangs in the fake radio.
        await until(
            lambda: rear.counters["requests"] > requests, "a request hanging in the radio", 10.0
        )
        t0 = time.monotonic()
        run.task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await run.task
        assert time.monotonic() - t0 < 1.0
        left = [t.get_name() for t in asyncio.all_tasks() if t.get_name().startswith("relayd:")]
        assert left == []
        assert poller.client._session is None  # closed, not leaked
        run.rig.rear.slow_s = 0.0
