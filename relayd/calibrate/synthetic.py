"""Synthetic calibration drives with known L0, n and sigma, as recordings: for tests and the bench.

A robot starts `start_m` from a node and drives straight away at `speed_m_s`; SIPs at
10 Hz carry the odometry, the rear AP is polled at 1 Hz. The received level is the
log-distance model plus log-normal shadowing (independent per poll, or a smooth
random field over the path with `corr_m`, as the simulator's) rounded to whole dBm as
airOS reports it; the radio's rate is the 802.11g rate of the local mean (minus a
multipath penalty) with a CCQ of 95 %. The messages have the layout of relayd's
recordings (docs/RECORDING.md: `/robot/sip`, `/link`), so `relayd calibrate
path-loss --from` reads them exactly as it reads a robot's.
"""

from __future__ import annotations

import dataclasses
import json
import math
import random
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from drivers.airos.model import LinkQuality, Station
from drivers.arcos.sip import Sip
from relayd.core.link.rates import RATE_TABLES


def _rate(power_dbm: float) -> float:
    for sens, rate in RATE_TABLES["802.11g"]:
        if power_dbm >= sens:
            return rate
    return 0.0


def _json(value: Any) -> Any:
    return json.loads(json.dumps(dataclasses.asdict(value)))


def drive_messages(
    *,
    l0_dbm: float,
    n: float,
    sigma_db: float,
    seed: int,
    start_m: float = 1.0,
    far_m: float = 30.0,
    speed_m_s: float = 0.15,
    corr_m: float | None = None,
    penalty_db: float = 0.0,
    poll_s: float = 1.0,
    near_m: float = 0.0,
) -> list[tuple[str, dict[str, Any]]]:
    """(topic, message) pairs in time order for one straight drive.

    With `near_m` the drive goes at a third of the speed until that far from the node,
    as `relayd calibrate path-loss --drive` does (relayd/calibrate/sources.py).
    """
    from relayd.calibrate.sources import NEAR_SPEED_SHARE

    rng = random.Random(seed)
    field = None
    if corr_m is not None:
        from relayd.sim.radio import ShadowField

        field = ShadowField(seed, corr_m)
    out: list[tuple[str, dict[str, Any]]] = []
    seq = 0
    t = 0.0
    next_poll = 0.5
    x_mm = 0.0
    while start_m + x_mm / 1000.0 <= far_m:
        v = speed_m_s * (NEAR_SPEED_SHARE if start_m + x_mm / 1000.0 < near_m else 1.0)
        sip = Sip(
            t=t,
            x_mm=x_mm,
            y_mm=0.0,
            theta_deg=0.0,
            left_mm_s=v * 1000,
            right_mm_s=v * 1000,
            battery_v=13.0,
            motors_enabled=True,
            estop=False,
            stall_left=False,
            stall_right=False,
            moving=True,
            sonar=(),
        )
        out.append(("/robot/sip", {"seq": seq, "t": t, "sip": _json(sip), "sonar_mm": [None] * 16}))
        seq += 1
        if t >= next_poll:
            d = start_m + x_mm / 1000.0
            shadow = sigma_db * (field.value(d, 0.0) if field is not None else rng.gauss(0.0, 1.0))
            mean = l0_dbm - 10.0 * n * math.log10(d) + shadow
            rate = _rate(mean - penalty_db)
            sta = Station(
                mac="02:00:00:00:00:01",
                signal_dbm=float(round(mean)),
                ccq_pct=95.0 if rate else 0.0,
                tx_mbps=rate,
                rx_mbps=rate,
                noise_dbm=-95.0,
            )
            q = LinkQuality(
                t=t,
                signal_dbm=None,
                rssi=None,
                noise_dbm=-95.0,
                ccq_pct=None,
                tx_mbps=None,
                rx_mbps=None,
                stations=(sta,),
                mode="ap",
            )
            out.append(("/link", {"seq": seq, "t": t, "side": "rear", "quality": _json(q)}))
            seq += 1
            next_poll += poll_s
        t = round(t + 0.1, 6)
        x_mm += 100.0 * v
    return out


#: The topics a path-loss drive records, and their schema names.
PATH_LOSS_SCHEMAS = {
    "/robot/sip": "relayd.SipEvent",
    "/link": "relayd.LinkEvent",
    "/wifi/rssi": "relayd.RssiEvent",
}


def write_recording(
    path: str | Path,
    messages: Sequence[tuple[str, dict[str, Any]]],
    schemas: dict[str, str] = PATH_LOSS_SCHEMAS,
    library: str = "relayd calibrate synthetic",
) -> None:
    """An MCAP file with these messages, one JSON channel per topic of `schemas` (topic ->
    schema name; relayd's layout)."""
    from mcap.writer import Writer

    with Path(path).open("wb") as f:
        w = Writer(f)
        w.start(profile="", library=library)
        channels: dict[str, int] = {}
        for topic, name in schemas.items():
            sid = w.register_schema(name=name, encoding="jsonschema", data=b'{"type": "object"}')
            channels[topic] = w.register_channel(
                topic=topic, message_encoding="json", schema_id=sid
            )
        for seq, (topic, doc) in enumerate(messages):
            ns = int(doc["t"] * 1e9)
            w.add_message(
                channel_id=channels[topic],
                log_time=ns,
                publish_time=ns,
                sequence=seq,
                data=json.dumps(doc, separators=(",", ":")).encode(),
            )
        w.finish()  # type: ignore[no-untyped-call]  # mcap ships no annotation for it
