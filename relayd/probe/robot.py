"""`relayd probe robot`: connect to a P3-AT, print its identity and every SIP. Read-only.

It never sends ENABLE 1, so the wheels cannot move; on exit it does the driver's
usual safe stop (VEL 0, ENABLE 0, CLOSE).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import sys

from drivers.arcos import ArcosRobot, HandshakeError, Sip
from drivers.transport.link import LinkError
from relayd.probe import emit, warnings_to_stderr


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--port",
        required=True,
        help="serial device or socket://host:port (MobileSim: socket://127.0.0.1:8101)",
    )
    parser.add_argument(
        "--baud", type=int, default=9600, help="first baud rate to try (default 9600)"
    )
    parser.add_argument(
        "--seconds",
        type=float,
        default=5.0,
        help="how long to print SIPs after connecting (default 5)",
    )
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument(
        "--subclass",
        default=None,
        help="override the subclass SYNC2 reports (odometry scale: p3at or p3at-sh)",
    )
    parser.add_argument(
        "--retries",
        type=int,
        default=10,
        help="unanswered SYNC packets (1 s each) before giving up (default 10)",
    )


def sip_record(sip: Sip, robot: ArcosRobot, t0: float) -> dict[str, object]:
    return {
        "t": round(sip.t - t0, 3),
        "x_mm": round(sip.x_mm, 1),
        "y_mm": round(sip.y_mm, 1),
        "theta_deg": round(sip.theta_deg, 2),
        "left_mm_s": sip.left_mm_s,
        "right_mm_s": sip.right_mm_s,
        "battery_v": sip.battery_v,
        "motors_enabled": sip.motors_enabled,
        "stall_left": sip.stall_left,
        "stall_right": sip.stall_right,
        "sonar_mm": list(robot.sonar.ranges_mm),
    }


def _text(rec: dict[str, object]) -> str:
    sonar = " ".join("-" if r is None else str(r) for r in rec["sonar_mm"])  # type: ignore[attr-defined]
    stall = ("L" if rec["stall_left"] else "-") + ("R" if rec["stall_right"] else "-")
    return (
        f"t={rec['t']:7.2f}s x={rec['x_mm']:8.1f} y={rec['y_mm']:8.1f} "
        f"th={rec['theta_deg']:7.2f} L={rec['left_mm_s']:6.0f} R={rec['right_mm_s']:6.0f} "
        f"bat={rec['battery_v']:.1f}V motors={'on' if rec['motors_enabled'] else 'off'} "
        f"stall={stall} sonar=[{sonar}]"
    )


async def run(args: argparse.Namespace) -> int:
    with warnings_to_stderr():
        return await _probe(args)


async def _probe(args: argparse.Namespace) -> int:
    robot = ArcosRobot(
        args.port,
        args.baud,
        subclass_override=args.subclass,
        max_misses=max(1, args.retries),
        enable_motors=False,
    )
    try:
        ident = await robot.connect()
    except (LinkError, HandshakeError) as exc:
        print(f"relayd probe robot: {exc}", file=sys.stderr)
        return 1
    if args.json:
        head = json.dumps(
            {"name": ident.name, "class": ident.robot_class, "subclass": ident.subclass}
        )
    else:
        head = (
            f"robot {ident.name!r}: class {ident.robot_class}, subclass {ident.subclass}, "
            f"baud {robot.current_baud}"
        )
    reader_gone = asyncio.Event()
    if not emit(head):
        reader_gone.set()
    t0 = robot.clock.now()

    def on_sip(sip: Sip) -> None:
        # A listener's exception is logged by the driver on every SIP: a closed stdout
        # is told to the main task instead, which stops the probe.
        if reader_gone.is_set():
            return
        rec = sip_record(sip, robot, t0)
        if not emit(json.dumps(rec) if args.json else _text(rec)):
            reader_gone.set()

    robot.add_listener(on_sip)
    task = asyncio.create_task(robot.run())
    try:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(reader_gone.wait(), max(0.0, args.seconds))
    finally:
        await robot.shutdown()
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
    return 0
