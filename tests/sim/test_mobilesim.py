"""The MobileSim tier: relayd against the vendor's ARCOS simulator, in real time.

One MobileSim process for the module (robots "leader", "relay1" and "relay2" in the
project's tests/fixtures/maps/corner.map), placed anew by each test; the office convoy
(through a doorway) starts its own, on the vendor's AMROffice.map beside the program
(skipped without it). Skipped, with the
reason, when RELAYD_MOBILESIM does not name the program (CI provisions it). Real time:
each run is short, and the assertions are ones every run must meet (no stall, the
leader arrives, the relays follow and end on the link rule), not exact figures. And
`relayd sim --engine mobilesim` stopped by SIGTERM (in order) or SIGKILL (no `finally`
at all) leaves no MobileSim or Xvfb of its own running.
"""

from __future__ import annotations

import asyncio
import math
import os
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from collections.abc import AsyncIterator
from pathlib import Path

import pytest
import pytest_asyncio

from drivers.arcos.driver import ArcosRobot
from relayd.sim.ariamap import MapLine, load_map
from relayd.sim.mapscenario import with_map
from relayd.sim.msbridge import ArcosBridge, BridgeBody
from relayd.sim.msengine import MobileSimRunner
from relayd.sim.msproc import MobileSim, MobileSimError, find_program
from relayd.sim.runner import SimResult
from relayd.sim.scenario import parse_scenario
from tests.sim.procs import children, running
from tests.support import ROOT, until

MAP = Path(__file__).resolve().parents[1] / "fixtures" / "maps" / "corner.map"
#: The office convoy's scenario (bench/engines.py runs it too: bench/RESULTS.md).
OFFICE = Path(__file__).resolve().parents[2] / "bench" / "amroffice_door.toml"
#: The office convoy's settling time after the person's goal (reached at about 37 s): the
#: relays stopped for good 47-57 s into the runs measured (bench/RESULTS.md); the bench
#: file gives 60 s.
SETTLE_S = 30.0
NAMES = ["leader", "relay1", "relay2"]
#: Where a robot a test does not use waits: the far end of the box corridor.
PARK = {"leader": (11000, 15400, 180), "relay1": (10200, 15400, 180), "relay2": (9400, 15400, 180)}

pytestmark = [pytest.mark.mobilesim, pytest.mark.asyncio(loop_scope="module")]


@pytest_asyncio.fixture(loop_scope="module", scope="module")
async def sim() -> AsyncIterator[MobileSim]:
    try:
        program = find_program()
    except MobileSimError as exc:
        pytest.skip(f"{exc} (the MobileSim tier needs it)")
    ms = MobileSim(program, MAP, NAMES)
    await ms.start()
    try:
        yield ms
    finally:
        await ms.stop()


async def _place(sim: MobileSim, name: str, pose: tuple[float, float, float]) -> BridgeBody:
    """Put a robot at `pose` (mm, mm, deg) through a short session of its own."""
    bridge = ArcosBridge(BridgeBody(name), sim.port(name), pose)
    await bridge.start()
    robot = ArcosRobot(bridge.url)
    try:
        await robot.connect()
        await until(lambda: bridge.body.simstats >= 2, f"{name}'s SIMSTAT", 15.0)
    finally:
        await robot.shutdown()
        await bridge.close()
    return bridge.body


async def _park(sim: MobileSim, *names: str) -> None:
    for n in names:
        await _place(sim, n, PARK[n])


async def test_probe_reads_mobilesim(sim: MobileSim) -> None:
    await until(lambda: _port_open(sim.port("relay1")), "relay1's port", 15.0)
    proc = subprocess.run(
        [sys.executable, "-m", "relayd", "probe", "robot", "--port", f"socket://127.0.0.1:{sim.port('relay1')}"],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "MobileSim" in proc.stdout and "p3at" in proc.stdout


def _port_open(port: int) -> bool:
    from relayd.sim.msproc import _listening

    return _listening(port)


async def test_drive_moves_the_true_pose(sim: MobileSim) -> None:
    await _park(sim, "leader", "relay2")
    bridge = ArcosBridge(BridgeBody("relay1"), sim.port("relay1"), (0.0, 0.0, 0.0))
    await until(lambda: _port_open(sim.port("relay1")), "relay1's port", 15.0)
    await bridge.start()
    robot = ArcosRobot(bridge.url, enable_motors=True)
    try:
        await robot.connect()
        task = __import__("asyncio").create_task(robot.run())
        await until(lambda: bridge.body.simstats > 0, "SIMSTAT", 15.0)
        assert math.hypot(bridge.body.x_mm, bridge.body.y_mm) < 50
        robot.set_wheels(300.0, 300.0)
        await until(lambda: bridge.body.x_mm > 600, "0.6 m driven east", 15.0)
        robot.stop()
        assert abs(bridge.body.y_mm) < 100 and not bridge.body.stalled
    finally:
        await robot.shutdown()
        task.cancel()
        await bridge.close()


def _seg_dist_m(px: float, py: float, ln: MapLine) -> float:
    ex, ey = ln.x2 - ln.x1, ln.y2 - ln.y1
    n2 = ex * ex + ey * ey
    u = 0.0 if n2 == 0 else max(0.0, min(1.0, ((px - ln.x1) * ex + (py - ln.y1) * ey) / n2))
    return math.hypot(px - ln.x1 - u * ex, py - ln.y1 - u * ey)


def _records_ok(records: list[dict[str, object]]) -> None:
    assert not any(any(r["stalled"]) for r in records)  # type: ignore[arg-type]


async def test_box_dead_ahead(sim: MobileSim, tmp_path: Path) -> None:
    """A box 2.3 m ahead on the line to a leader standing still beyond it: MobileSim's own
    sonar shows it, and the relay turns off the straight way before it (a detour round the
    sonar map, or the escape), never touching. (Getting all the way round takes longer
    than a short test's business: bench/RESULTS.md.)"""
    await _park(sim, "relay2")
    doc = {
        "name": "ms-box",
        "environment": "outdoor",
        "duration_s": 22,
        "settle_after_goal_s": 22,
        "relays": 1,
        "map_route": "straight",
        "command_center": {"x": 1.5, "y": 14.0},
        "leader": {"kind": "robot", "waypoints": [{"x": 11.0, "y": 14.0}]},
        "relay": [{"name": "relay1", "x": 3.7, "y": 14.0}],
    }
    sc = parse_scenario(with_map(doc, MAP))
    res = await MobileSimRunner(sc, sim=sim, out_dir=tmp_path).run()
    _records_ok(res.records)
    relay = [r["relays"][0] for r in res.records]
    reasons = {r["reason"] for r in relay}
    assert reasons & {"detour", "avoiding"}, f"the relay never went round the box: {reasons}"
    # It drove toward the box, and while on the line to it its front (0.31 m ahead of its
    # centre) never reached the box's near face at x = 6.0.
    on_line = [r["x"] + 0.313 for r in relay if abs(r["y"] - 14.0) < 0.3]
    assert on_line and max(on_line) < 6.0, f"relay1's front got to x = {max(on_line):.2f}"
    assert max(r["x"] for r in relay) + 0.313 > 5.0, "relay1 never drove toward the box"


def _convoy_ok(res: SimResult, map_path: Path, relay1_m: float) -> None:
    """The leader arrives with the link held, no relay stalls or comes within 0.3 m of a
    wall line, relay1 travels more than `relay1_m` and every relay ends on the link rule."""
    _records_ok(res.records)
    s = res.summary
    assert s["goal_reached"], s
    assert s["link_broken_at_s"] is None
    lines = load_map(map_path).lines
    for rec in res.records:
        for r in rec["relays"]:
            near = [ln for ln in lines if min(ln.x1, ln.x2) - 1 < r["x"] < max(ln.x1, ln.x2) + 1
                    and min(ln.y1, ln.y2) - 1 < r["y"] < max(ln.y1, ln.y2) + 1]  # fmt: skip
            clear = min((_seg_dist_m(r["x"], r["y"], ln) for ln in near), default=math.inf)
            assert clear > 0.3, f"{r['name']} {clear:.2f} m from a wall at t = {rec['t']}"
    assert s["followers"][0]["travelled_m"] > relay1_m, s["followers"][0]
    for f in s["followers"]:
        assert f["stopped_reason"] in ("leader_near", "rear_weak"), f


async def test_two_relay_convoy_through_a_corner(sim: MobileSim, tmp_path: Path) -> None:
    doc = {"name": "ms-corner", "duration_s": 75, "settle_after_goal_s": 25}
    sc = parse_scenario(with_map(doc, MAP))
    leader = sc.leader.model_copy(update={"kind": "robot", "speed_m_s": 0.3})
    sc = sc.model_copy(update={"leader": leader})
    res = await MobileSimRunner(sc, sim=sim, out_dir=tmp_path).run()
    # relay1 follows the leader round the corner; relay2 moves only if the radio asks it to.
    _convoy_ok(res, MAP, 1.5)
    assert (tmp_path / "trace.jsonl").stat().st_size > 0


async def test_two_relay_convoy_through_the_office(tmp_path: Path) -> None:
    """bench/amroffice_door.toml on the vendor's AMROffice.map: a person walks west along
    one corridor, south down the next and through the door in its west wall into the room
    behind; both relays follow round the corner (relay1 down to the door, relay2 into the
    second corridor) and end on the link rule."""
    try:
        office = find_program().parent / "AMROffice.map"
    except MobileSimError as exc:
        pytest.skip(f"{exc} (the MobileSim tier needs it)")
    if not office.is_file():
        pytest.skip(f"no {office.name} beside the MobileSim program")
    doc = tomllib.loads(OFFICE.read_text())
    doc["settle_after_goal_s"] = SETTLE_S
    sc = parse_scenario(with_map(doc, office))
    res = await MobileSimRunner(sc, program=find_program(), out_dir=tmp_path).run()
    _convoy_ok(res, office, 3.5)
    assert res.summary["leader_arrived"] and res.summary["relays_ok"], res.summary
    # The person went through the doorway (its middle at (-4.52, -2.75)) into the room.
    assert any(
        math.hypot(r["leader"]["x"] + 4.52, r["leader"]["y"] + 2.75) < 0.3 for r in res.records
    )
    assert res.records[-1]["leader"]["x"] < -5.0, res.records[-1]["leader"]
    # relay1 ends down the north-south corridor (south of y = -1.5), toward the door;
    # relay2 has turned the corner out of the east-west corridor toward it (y < 0).
    relay1, relay2 = res.records[-1]["relays"]
    assert relay1["y"] < -1.5, f"relay1 ended at ({relay1['x']:.2f}, {relay1['y']:.2f})"
    assert relay2["y"] < 0.0, f"relay2 ended at ({relay2['x']:.2f}, {relay2['y']:.2f})"


#: How long `relayd sim` may take to exit after SIGTERM, and its MobileSim and Xvfb to be
#: gone after it: measured 0.2 s from the signal to the exit, and nothing left at the exit.
STOPPED_S = 5.0


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
async def test_a_stopped_sim_leaves_no_mobilesim_or_xvfb(
    tmp_path: Path, sig: signal.Signals
) -> None:
    """One relay in the corner map, stopped once it is up: SIGTERM is an orderly stop
    (exit 0), SIGKILL leaves it to the kernel's parent-death signal. Either way
    MobileSim and Xvfb (where relayd started one) are gone within STOPPED_S."""
    try:
        program = find_program()
    except MobileSimError as exc:
        pytest.skip(f"{exc} (the MobileSim tier needs it)")
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "relayd", "sim", "--engine", "mobilesim", "--mobilesim",
        str(program), "--map", str(MAP), "--relays", "1", "--seconds", "120", "--no-plots",
        "--out", str(tmp_path / "out"),
        env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"},
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
    )  # fmt: skip
    lines: list[str] = []

    async def drain() -> None:
        assert proc.stdout is not None
        async for raw in proc.stdout:
            lines.append(raw.decode(errors="replace").rstrip("\n"))

    reader = asyncio.create_task(drain())
    try:
        # Its relay's API is announced once MobileSim is up and the relay reads its robot.
        await until(lambda: any("API and live page" in ln for ln in lines), "the relay up", 60.0)
        kids = children(proc.pid)
        assert "MobileSim" in kids, (kids, lines)
        if shutil.which("Xvfb"):
            assert "Xvfb" in kids, kids
        t0 = time.monotonic()
        proc.send_signal(sig)
        async with asyncio.timeout(STOPPED_S):
            code = await proc.wait()
        await until(
            lambda: not any(running(k) for k in kids.values()),
            f"{sorted(kids)} gone after {sig.name}",
            max(0.1, STOPPED_S - (time.monotonic() - t0)),
        )
        print(f"{sig.name} -> exit and nothing left: {time.monotonic() - t0:.2f} s")
        if sig == signal.SIGTERM:
            assert code == 0, lines
            assert "relayd sim: stopped before the end of the run" in lines, lines
        else:
            assert code == -signal.SIGKILL
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
        await reader
