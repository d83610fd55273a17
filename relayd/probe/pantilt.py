"""`relayd probe pantilt`: move (optionally) and read back one servo of the pan-tilt controller.

With `--angle` the servo is commanded (clamped to `--limits`), the probe waits for the
move to finish (at most `--wait` seconds) and then reads the angle back from the
controller. With `--json` it prints one line `{"channel","angle_deg","moving"}`.
Exit codes: 0 read, 1 the controller could not be opened or did not answer (reason on
stderr), 2 usage error (bad calibration, channel the controller does not have).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable

from drivers.pantilt import PROTOCOLS, MaestroPanTilt, PanTiltError, ServoCalibration, make_pantilt
from drivers.transport.link import LinkError
from relayd.probe import emit, warnings_to_stderr


def _floats(count: int) -> Callable[[str], tuple[float, ...]]:
    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {count} comma-separated numbers") from None
        if len(values) != count:
            raise argparse.ArgumentTypeError(f"expected {count} comma-separated numbers")
        return values

    return parse


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--port", required=True, help="serial device or socket:// URL of the servo controller"
    )
    parser.add_argument(
        "--protocol",
        choices=sorted(PROTOCOLS),
        required=True,
        help="controller protocol: Pololu Maestro compact or Lynxmotion SSC-32",
    )
    parser.add_argument(
        "--channel", type=int, required=True, help="servo channel on the controller"
    )
    parser.add_argument(
        "--angle",
        type=float,
        default=None,
        help="move the servo to this angle in degrees (counter-clockwise positive)",
    )
    parser.add_argument(
        "--speed",
        type=float,
        default=None,
        help="slew speed in deg/s for the move (default: the controller's)",
    )
    parser.add_argument(
        "--baud",
        type=int,
        default=None,
        help="baud rate (default 115200 for maestro, 9600 for ssc32)",
    )
    parser.add_argument(
        "--pulse-us",
        type=_floats(3),
        default=(1000.0, 1500.0, 2000.0),
        metavar="P1,P2,P3",
        help="pulse widths at -90,0,+90 deg (default 1000,1500,2000)",
    )
    parser.add_argument(
        "--limits",
        type=_floats(2),
        default=(-90.0, 90.0),
        metavar="LO,HI",
        help="allowed angle range in degrees (default -90,90)",
    )
    parser.add_argument(
        "--wait",
        type=float,
        default=5.0,
        help="longest wait for the move to finish, seconds (default 5)",
    )
    parser.add_argument(
        "--timeout", type=float, default=0.5, help="reply timeout in seconds (default 0.5)"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _err(message: str) -> None:
    print(f"relayd probe pantilt: {message}", file=sys.stderr)


async def run(args: argparse.Namespace) -> int:
    # Before the driver binds its logger.
    with warnings_to_stderr():
        return await _probe(args)


async def _probe(args: argparse.Namespace) -> int:
    try:
        cal = ServoCalibration(pulse_us=args.pulse_us, limits_deg=args.limits)
        pt = make_pantilt(
            args.protocol, args.port, args.baud, {args.channel: cal}, reply_timeout_s=args.timeout
        )
    except ValueError as exc:
        _err(str(exc))
        return 2
    if args.angle is not None and cal.clamp(args.angle) != args.angle:
        # A bring-up tool must not move somewhere else than asked: refuse, move nothing.
        _err(
            f"{args.angle:g} deg is outside the limits {cal.limits_deg[0]:g}..{cal.limits_deg[1]:g} deg "
            "(widen them with --limits if the servo really travels that far)"
        )
        return 2
    try:
        await pt.connect()
        if args.speed is not None:
            await pt.set_speed(args.channel, args.speed)
        if args.angle is not None:
            await pt.set_angle(args.channel, args.angle)
            await pt.wait_stopped(args.wait)
        angle = await pt.get_angle(args.channel)
        moving = await pt.is_moving()
        errors = await pt.get_errors() if isinstance(pt, MaestroPanTilt) else ()
    except (LinkError, PanTiltError) as exc:
        _err(str(exc))
        return 1
    except ValueError as exc:
        _err(str(exc))
        return 2
    finally:
        await pt.close()
    # The pulse width is what calibration writes into scan_pulse_us / link_pulse_us.
    pulse_us = cal.angle_to_pulse_us(angle)
    # One line: a reader that closed before it is no failure of the controller.
    if args.json:
        emit(
            json.dumps(
                {
                    "channel": args.channel,
                    "angle_deg": round(angle, 2),
                    "pulse_us": round(pulse_us, 1),
                    "moving": moving,
                }
            )
        )
    else:
        emit(
            f"channel {args.channel}: {angle:.2f} deg, pulse {pulse_us:.0f} us, {'moving' if moving else 'still'}"
            + (f", controller errors: {', '.join(errors)}" if errors else "")
        )
    return 0
