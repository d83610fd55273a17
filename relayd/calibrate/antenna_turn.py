"""`relayd calibrate antenna --turn-steps N`: the relay turns itself in place to measure its back half.

A servo sweep sees about +-90 deg of the antenna's pattern; the back half (a Yagi's back
lobe, a panel's front-to-back ratio) needs the robot itself turned. With `--turn-steps N`
(started on purpose: the robot moves) the calibration collects `--sweeps` scans at its
heading, turns in place by 360/N deg, collects again, and so on N times, then stops:

- **Through the daemon's motion path.** It switches the daemon to manual mode and turns
  with `POST /api/drive` (one wheel back, one forward, `--turn-speed-mm-s`, at most
  MAX_TURN_MM_S), resent every DRIVE_RESEND_S: the daemon's dead-man time, speed limit and
  manual-mode obstacle rule stay in force, and a lost calibration host stops the wheels
  within half a second. It watches `pose.theta_deg` on /status and stops the wheels when
  the step is turned (or the daemon says it stopped the robot, or the step takes longer
  than TURN_TIMEOUT_S: SourceError).
- **A still robot for every sweep kept.** After each turn the wheels are stopped and the
  first scan that ends is dropped (it may have begun while turning); only whole sweeps at
  rest enter.
- **Hold at the end**, on every path out (an error, Ctrl-C): the daemon is left in hold mode.

The samples carry the heading /status reported, so `relayd.calibrate.antenna.measure_pattern`
puts each at its own off-axis angle, as it does for a recording of a relay turned by hand.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

from relayd.calibrate.antenna import AntennaSample
from relayd.calibrate.antenna_sources import samples_from_status
from relayd.calibrate.sources import DaemonApi, SourceError
from relayd.calibrate.sources import _num as _num

#: Resend the drive command this often: well inside the daemon's 0.5 s dead-man time.
DRIVE_RESEND_S = 0.2
#: A turn in place, not a drive: at most this wheel speed (mm/s; 100 mm/s turns a P3-AT
#: at about 30 deg/s).
MAX_TURN_MM_S = 150.0
#: A step that has not turned after this long (s) ends the calibration.
TURN_TIMEOUT_S = 30.0
#: The step is done within this much (deg): the robot coasts a little after the stop.
TURN_TOLERANCE_DEG = 2.0
#: Reasons that end a turn: the daemon refused to move the robot.
STOP_REASONS = ("obstacle", "no_sip", "deadman", "shutdown")


@dataclass(frozen=True, slots=True)
class TurnOptions:
    url: str
    token: str
    steps: int
    sweeps_per_step: int
    seconds_per_step: float = 120.0
    speed_mm_s: float = 100.0
    hz: float = 5.0


def wrap180(angle_deg: float) -> float:
    return math.remainder(angle_deg, 360.0)


# Complexity: one session's three phases (collect, turn, hold), each with its own stop conditions.
async def sample_turning(  # noqa: C901
    opts: TurnOptions, *, progress: Callable[[str], None] | None = None
) -> list[AntennaSample]:
    """Sweeps at `opts.steps` headings 360/steps apart, the relay turned in place between them."""
    import aiohttp

    if opts.steps < 2:
        raise ValueError(f"turn steps must be at least 2, got {opts.steps}")
    if not 0.0 < opts.speed_mm_s <= MAX_TURN_MM_S:
        raise ValueError(f"turn speed must be within 0..{MAX_TURN_MM_S:g} mm/s")
    base = opts.url.rstrip("/")
    if "://" not in base:
        base = "http://" + base
    step_deg = 360.0 / opts.steps
    say = progress or (lambda _msg: None)
    timeout = aiohttp.ClientTimeout(total=3.0)
    headers = {"Authorization": f"Bearer {opts.token}"}
    loop = asyncio.get_running_loop()
    out: list[AntennaSample] = []
    async with aiohttp.ClientSession(timeout=timeout, headers=headers) as session:
        api = DaemonApi(session, base)
        post, status = api.post, api.status

        async def collect(first_sweep: int) -> list[AntennaSample]:
            """`sweeps_per_step` whole sweeps at rest: the scan on show when it starts and
            the first one to end after it (it may have begun while turning) are dropped."""
            sweeps: list[list[AntennaSample]] = []
            last_t: float | None = None
            seen_one = False
            start = loop.time()
            while len(sweeps) < opts.sweeps_per_step + 1:
                if loop.time() - start > opts.seconds_per_step:
                    raise SourceError(
                        f"no {opts.sweeps_per_step} sweeps within {opts.seconds_per_step:g} s"
                    )
                new, last_t = samples_from_status(await status(), 0, last_t)
                if new and seen_one:
                    sweeps.append(new)
                seen_one = seen_one or bool(new)
                await asyncio.sleep(1.0 / opts.hz)
            return [
                replace(s, sweep=first_sweep + k) for k, sw in enumerate(sweeps[1:]) for s in sw
            ]

        async def heading() -> float:
            th = _num((await status())["pose"].get("theta_deg"))
            if th is None:
                raise SourceError("/status: pose.theta_deg is missing")
            return th

        async def turn(delta_deg: float) -> None:
            """Turn in place by delta_deg (ccw +), summing the heading's small increments."""
            s = math.copysign(opts.speed_mm_s, delta_deg)
            prev, turned = await heading(), 0.0
            start = next_drive = loop.time()
            try:
                while abs(turned) < abs(delta_deg) - TURN_TOLERANCE_DEG:
                    now = loop.time()
                    if now - start > TURN_TIMEOUT_S:
                        raise SourceError(
                            f"turned {turned:.0f} of {delta_deg:.0f} deg in {TURN_TIMEOUT_S:g} s"
                        )
                    if now >= next_drive:
                        await post("/api/drive", {"left_mm_s": -s, "right_mm_s": s})
                        next_drive = now + DRIVE_RESEND_S
                    # The heading more often than the command: the stop comes on time.
                    await asyncio.sleep(min(1.0 / opts.hz, DRIVE_RESEND_S))
                    doc = await status()
                    if doc.get("reason") in STOP_REASONS:
                        raise SourceError(f"the daemon stopped the robot: {doc.get('reason')}")
                    th = _num(doc["pose"].get("theta_deg"))
                    if th is not None:
                        turned += wrap180(th - prev)
                        prev = th
            finally:
                await asyncio.shield(post("/api/drive", {"left_mm_s": 0.0, "right_mm_s": 0.0}))

        try:
            await post("/api/mode", {"mode": "manual"})
            for k in range(opts.steps):
                got = await collect(len({s.sweep for s in out}))
                out += got
                say(f"heading {got[0].heading_deg:+.0f} deg: {len({s.sweep for s in got})} sweeps")
                if k < opts.steps - 1:
                    say(f"turning {step_deg:.0f} deg")
                    await turn(step_deg)
        finally:
            try:
                await asyncio.shield(post("/api/mode", {"mode": "hold"}))
            except (aiohttp.ClientError, TimeoutError, SourceError):
                say("could not set hold mode: the dead-man time stopped the wheels")
    return out
