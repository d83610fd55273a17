"""A connection flood on the API does not stop the robot.

`relayd run` in a subprocess under the default descriptor limit (RLIMIT_NOFILE 1024,
soft and hard, as systemd leaves it without LimitNOFILE) drives a FakeRig toward a
far leader; the rig runs in a process of its own (tests/api/rig_proc.py), so a busy test
process cannot starve the fake devices into a stop of their own making. tests/api/flood.py,
in a fourth process, then opens 1,100 idle connections
and 100 slow-header clients to the API and holds them. Before the guard in
relayd/api/guard.py this exhausted the daemon's descriptors: the RSSI source failed
with EMFILE, the robot stopped on rssi_stale, /healthz timed out and asyncio logged
the failed accept tens of thousands of times. Now:

- the robot keeps driving: the fake robot's wheel target never drops to zero and the
  daemon never reports a stop, during the flood or after it. One cause of a stop is not
  the flood's and is excused: the rig's own process starved by a loaded machine (CI runs
  three test workers on two cores), so that the fake robot itself sent no SIP for longer
  than relayd's lost_after_s. relayd must stop a silent robot; the rig records each such
  silence (tests/api/rig_proc.py) and only a device-silence stop inside one is excused;
- /healthz answers (200) within 10 s of the flood being in place, on a new connection;
- the whole log stays under 1 MB.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import re
import resource
import signal
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from tests.support import until

pytestmark = pytest.mark.slow

HERE = Path(__file__).resolve().parent
SCAN = {"samples": 9, "width_deg": 120, "settle_s": 0.02}
PANTILT = {"speed_deg_s": 1000}
IDLE, SLOW = 1100, 100
#: Past the server's 10 s idle timeout (idle and slow-header clients are cut once, by it:
#: the figures must show the cut) and past the /healthz window below: a longer hold only
#: repeats the same. (16 s until the hold had to be past the cut to count.)
HOLD_S = 13.0
#: /healthz answered 1.3 s into the flood on a loaded machine (load average 8 on 2 cores).
HEALTHZ_WITHIN_S = 10.0
MAX_LOG_BYTES = 1_000_000
_PRIORITY = re.compile(r"^<\d>")
#: A stop for a silent device is excused from the start of the rig's own silence until
#: this long after its end: relayd sees the next SIP, steps, and reports driving again.
EXCUSE_AFTER_S = 1.0
#: What a silent rig causes (its robot, its RSSI file, its servo, its rear radio): the
#: control law's fault reasons, and the ARCOS session's warning of a silent robot.
SILENCE_REASONS = {"no_sip", "rssi_stale", "scan_stale", "scan_servo", "rear_link_stale"}
SILENCE_EVENTS = {"robot_stale"}


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _default_nofile() -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (1024, 1024))


def _events(log: Path) -> list[dict[str, Any]]:
    out = []
    for line in log.read_text(errors="replace").splitlines():
        with contextlib.suppress(ValueError):
            doc = json.loads(_PRIORITY.sub("", line))
            if isinstance(doc, dict):
                out.append(doc)
    return out


def _wall(event: dict[str, Any]) -> float:
    """A log event's time (structlog's ISO UTC timestamp) as time.time() would give it."""
    stamp = str(event.get("timestamp", "")).replace("Z", "+00:00")
    try:
        return datetime.fromisoformat(stamp).timestamp()
    except ValueError:
        return math.nan  # no time: never excused


async def _healthz(port: int) -> int | None:
    """/healthz on a fresh connection: the status code, or None if it did not answer."""
    try:
        async with (
            aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=2.0)) as session,
            session.get(f"http://127.0.0.1:{port}/healthz") as resp,
        ):
            await resp.read()
            return resp.status
    except (aiohttp.ClientError, OSError, TimeoutError):
        return None


async def _status(port: int) -> dict[str, Any] | None:
    try:
        async with (
            aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=2.0)) as session,
            session.get(f"http://127.0.0.1:{port}/status") as resp,
        ):
            doc: dict[str, Any] = await resp.json()
            return doc
    except (aiohttp.ClientError, OSError, TimeoutError, ValueError):
        return None


async def test_connection_flood_does_not_stop_the_robot(tmp_path: Path) -> None:
    _soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < IDLE + SLOW + 256:
        pytest.skip(f"the flood needs {IDLE + SLOW + 256} descriptors; hard limit {hard}")
    # Far ahead: the robot drives for the whole test, never reaching threshold_l.
    port = _free_port()
    config_kw = {
        "secrets_in_files": True,
        "scan": SCAN,
        "pantilt": PANTILT,
        "api_port": port,
        "log": {"format": "json"},
    }
    rig = await asyncio.create_subprocess_exec(
        sys.executable,
        str(HERE / "rig_proc.py"),
        str(tmp_path),
        "60.0",
        "0.0",
        json.dumps(config_kw),
        stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE,
    )
    assert rig.stdin is not None and rig.stdout is not None
    rig_in, rig_out = rig.stdin, rig.stdout

    async def ask(command: str) -> dict[str, Any]:
        rig_in.write(command.encode() + b"\n")
        await rig_in.drain()
        answer: dict[str, Any] = json.loads(await asyncio.wait_for(rig_out.readline(), 30.0))
        return answer

    relayd: subprocess.Popen[bytes] | None = None
    flood: asyncio.subprocess.Process | None = None
    log_path = tmp_path / "relayd.log"
    try:
        config = json.loads(await asyncio.wait_for(rig_out.readline(), 60.0))["config"]
        with log_path.open("wb") as log_file:
            relayd = subprocess.Popen(
                [sys.executable, "-m", "relayd", "run", "-c", config],
                stdout=log_file,
                stderr=subprocess.STDOUT,
                preexec_fn=_default_nofile,
            )

        async def driving() -> bool:
            assert relayd is not None
            if relayd.poll() is not None:
                raise AssertionError(
                    f"relayd exited {relayd.returncode}: {log_path.read_text()[-3000:]}"
                )
            doc = await _status(port)
            return (
                doc is not None
                and doc["state"] == "driving"
                and (await ask("vel"))["target_vel_mm_s"] > 0
            )

        try:
            await until(driving, "the robot to drive", timeout_s=60.0, poll_s=0.2)
        except AssertionError:
            pytest.fail("the robot never started driving:\n" + log_path.read_text()[-3000:])

        # Watch the wheels from here on: the fake robot's target speed, every 20 ms (in
        # the rig's process, which samples it).
        assert (await ask("watch"))["watching"]
        mark = len(_events(log_path))
        flood = await asyncio.create_subprocess_exec(
            sys.executable,
            str(HERE / "flood.py"),
            str(port),
            "--idle",
            str(IDLE),
            "--slow",
            str(SLOW),
            "--hold-s",
            str(HOLD_S),
            stdout=asyncio.subprocess.PIPE,
        )
        assert flood.stdout is not None
        line = await asyncio.wait_for(flood.stdout.readline(), 90.0)
        assert json.loads(line).get("flooding"), line
        t_flood = time.monotonic()

        # /healthz answers again on a fresh connection, while the flood holds.
        t_ok: float | None = None

        async def healthy() -> bool:
            return await _healthz(port) == 200

        with contextlib.suppress(AssertionError):  # t_ok stays None: asserted below, with the log
            await until(healthy, "/healthz", timeout_s=HEALTHZ_WITHIN_S + 5, poll_s=0.2)
            t_ok = time.monotonic()
        figures_line = await asyncio.wait_for(flood.stdout.readline(), HOLD_S + 60)
        await flood.wait()
        figures = json.loads(figures_line)
        # And after the flood: still driving, still answering, for ten more SIP cycles of
        # the robot's own (its commands keep coming: the control loop runs on).
        before = await ask("count")

        async def ten_more_cycles() -> bool:
            now = await ask("count")
            return (
                now["sips_sent"] >= before["sips_sent"] + 10
                and now["commands"] >= before["commands"] + 10
            )

        await until(
            ten_more_cycles,
            "ten more SIP cycles with commands after the flood",
            timeout_s=30.0,
            poll_s=0.1,
        )
        stops = (await ask("stops"))["stops"]
        silences = (await ask("silences"))["silences"]
        after = await _status(port)
    finally:
        if flood is not None and flood.returncode is None:
            flood.kill()
            await flood.wait()
        if relayd is not None and relayd.poll() is None:
            relayd.send_signal(signal.SIGTERM)
            try:
                await asyncio.to_thread(relayd.wait, 10)
            except subprocess.TimeoutExpired:
                relayd.kill()
                await asyncio.to_thread(relayd.wait)
        rig_in.close()  # end of stdin: the rig stops and exits
        try:
            await asyncio.wait_for(rig.wait(), 30.0)
        except TimeoutError:
            rig.kill()
            await rig.wait()

    log_bytes = log_path.stat().st_size
    events = _events(log_path)
    names = [e.get("event") for e in events]
    events = events[: names.index("signal")] if "signal" in names else events  # not our SIGTERM
    tail = log_path.read_text(errors="replace")[-3000:]
    print(
        f"flood {figures}; /healthz 200 after {None if t_ok is None else round(t_ok - t_flood, 2)} s; "
        f"log {log_bytes} bytes"
    )
    assert figures["idle_connected"] + figures["slow_connected"] > 200, figures  # a real flood
    # The hold lasted past the server's idle timeout: it cut the slow-header clients.
    assert figures["slow_cut_by_server"] > 0, figures
    assert t_ok is not None and t_ok - t_flood <= HEALTHZ_WITHIN_S, (
        f"/healthz not answering within {HEALTHZ_WITHIN_S} s of the flood\n{tail}"
    )
    silent_s = sum(m1 - m0 for m0, m1 in (span["mono"] for span in silences))
    print(f"the rig's own silences: {len(silences)}, {silent_s:.2f} s in all")
    # Most of the flood must be a real test: a rig silent for half of it proves nothing.
    assert silent_s < HOLD_S / 2, f"the rig itself was silent {silent_s:.1f} s: {silences}"

    def excused(t: float, clock: str) -> bool:
        return any(bool(s[clock][0] <= t <= s[clock][1] + EXCUSE_AFTER_S) for s in silences)

    def excused_event(e: dict[str, Any]) -> bool:
        silent = e.get("reason") in SILENCE_REASONS or e.get("event") in SILENCE_EVENTS
        return silent and excused(_wall(e), "wall")

    stops = [t for t in stops if not excused(t, "mono")]
    assert stops == [], f"the wheels stopped {len(stops)} times during the flood\n{tail}"
    not_driving = [
        e
        for e in events[mark:]
        if e.get("event") == "drive_state" and e.get("state") != "driving"
        if not excused_event(e)
    ]
    assert not_driving == [], (not_driving[:5], silences)
    stale = [e for e in events if "stale" in json.dumps(e) and not excused_event(e)]
    assert stale == [], (stale[:5], silences)
    assert after is not None and after["state"] == "driving", after
    assert log_bytes < MAX_LOG_BYTES, f"log grew to {log_bytes} bytes"
    assert not any(
        "EMFILE" in json.dumps(e) or "Too many open files" in json.dumps(e) for e in events
    )
