"""Where `relayd calibrate path-loss` gets its readings: a recording, or a running relayd.

A reading is one RSSI (and, on the rear link, the airOS rates and CCQ) with the
odometry distance from the stationary node at that moment:

    distance = start_distance_m + |pose - pose at the first SIP|

(a straight drive away from the node, so the distance driven adds to the start gap).

- **A recording** (`--from FILE`, docs/RECORDING.md): the MCAP channels `/robot/sip`
  (odometry), `/link` (the airOS polls; `side` rear or front) and `/wifi/rssi` (the
  Yagi adapter's samples), read by channel name with the `mcap` library. Each
  reading takes the distance of the last SIP before it.
- **A running relayd** (`--url`): its `/status`, polled a few times a second (pose,
  `links.rear` or `rssi_leader_dbm`). Read-only unless `--drive`: then the robot is put
  in manual mode and sent the same low forward speed over the daemon's own
  `POST /api/drive`, so every fail-safe of the daemon applies as to an operator's
  command (the dead-man time, the obstacle guard, no SIP, ...); no second driving loop
  exists. It goes at a third of that speed in the first `near_m` metres, where the
  readings that pin L0 are, and ends in hold mode, whatever happened.
"""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import aiohttp

#: Which link a calibration measures.
LINKS = ("rear", "front", "leader")


@dataclass(frozen=True, slots=True)
class Reading:
    t: float
    distance_m: float
    rssi_dbm: float
    tx_mbps: float | None = None
    rx_mbps: float | None = None
    ccq_pct: float | None = None


class SourceError(Exception):
    """A recording or robot that gives no calibration data; the message says why."""


def _num(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def _obj(value: Any) -> dict[str, Any]:
    """A message's sub-object, or an empty one where a file holds something else (a list,
    a number): that message gives no reading, the rest of the file still does."""
    return value if isinstance(value, dict) else {}


def link_reading(
    quality: dict[str, Any],
) -> tuple[float | None, float | None, float | None, float | None]:
    """(signal, tx, rx, ccq) of one airOS poll: the strongest station's, else the radio's own."""
    listed = quality.get("stations")
    stations = [
        s
        for s in (listed if isinstance(listed, list) else [])
        if isinstance(s, dict) and _num(s.get("signal_dbm"))
    ]
    if stations:
        best = max(stations, key=lambda s: _num(s.get("signal_dbm")) or -999.0)
        return (
            _num(best.get("signal_dbm")),
            _num(best.get("tx_mbps")),
            _num(best.get("rx_mbps")),
            _num(best.get("ccq_pct")),
        )
    return (
        _num(quality.get("signal_dbm")),
        _num(quality.get("tx_mbps")),
        _num(quality.get("rx_mbps")),
        _num(quality.get("ccq_pct")),
    )


def readings_from_messages(
    messages: Iterable[tuple[str, dict[str, Any]]],
    *,
    link: str = "rear",
    start_distance_m: float = 1.0,
) -> list[Reading]:
    """Readings from (topic, decoded message) pairs in time order, as a recording holds them."""
    if link not in LINKS:
        raise ValueError(f"link must be one of {', '.join(LINKS)}")
    origin: tuple[float, float] | None = None
    distance: float | None = None
    out: list[Reading] = []
    for topic, doc in messages:
        if topic == "/robot/sip":
            sip = _obj(doc.get("sip"))
            x, y = _num(sip.get("x_mm")), _num(sip.get("y_mm"))
            if x is None or y is None:
                continue
            if origin is None:
                origin = (x, y)
            distance = start_distance_m + math.hypot(x - origin[0], y - origin[1]) / 1000.0
        elif distance is None:
            continue  # no odometry yet: nothing to place the reading at
        elif topic == "/link" and link in ("rear", "front") and doc.get("side") == link:
            t = _num(doc.get("t"))
            signal, tx, rx, ccq = link_reading(_obj(doc.get("quality")))
            if t is not None and signal is not None:
                out.append(Reading(t, distance, signal, tx, rx, ccq))
        elif topic == "/wifi/rssi" and link == "leader":
            sample = _obj(doc.get("sample"))
            t, rssi = _num(doc.get("t")), _num(sample.get("rssi_dbm"))
            if t is not None and rssi is not None and sample.get("fresh") is True:
                out.append(Reading(t, distance, rssi))
    return out


def iter_recording(path: str | Path) -> Iterator[tuple[str, dict[str, Any]]]:
    """The odometry, link and RSSI messages of an MCAP recording, in log-time order."""
    from relayd.record.reader import RecordingError, iter_messages

    try:
        # The one reader of recordings: the CRCs and the chunk caps replay has, too.
        messages = iter_messages(Path(path), frozenset({"/robot/sip", "/link", "/wifi/rssi"}))
    except RecordingError as exc:
        raise SourceError(f"not a readable MCAP recording: {exc}") from None
    for topic, _t, data in messages:
        try:
            doc = json.loads(data)
        except (ValueError, RecursionError):
            continue  # one undecodable message loses one reading, not the calibration
        if isinstance(doc, dict):
            yield topic, doc


def readings_from_recording(
    path: str | Path, *, link: str = "rear", start_distance_m: float = 1.0
) -> list[Reading]:
    readings = readings_from_messages(
        iter_recording(path), link=link, start_distance_m=start_distance_m
    )
    if not readings:
        raise SourceError(
            f"{path}: no {link} link readings with odometry (channels /robot/sip and "
            f"{'/wifi/rssi' if link == 'leader' else '/link'})"
        )
    return readings


# -- a running relayd --------------------------------------------------------------------


def status_reading(
    doc: dict[str, Any], *, link: str, origin: tuple[float, float] | None, start_distance_m: float
) -> tuple[Reading | None, tuple[float, float] | None]:
    """One /status document -> a reading (or None) and the odometry origin."""
    pose = doc.get("pose") or {}
    x, y = _num(pose.get("x_mm")), _num(pose.get("y_mm"))
    if x is None or y is None:
        return None, origin
    if origin is None:
        origin = (x, y)
    distance = start_distance_m + math.hypot(x - origin[0], y - origin[1]) / 1000.0
    t = _num(doc.get("uptime_s")) or 0.0
    if link == "leader":
        rssi = _num(doc.get("rssi_leader_dbm"))
        return (Reading(t, distance, rssi) if rssi is not None else None), origin
    li = (doc.get("links") or {}).get(link) or {}
    signal = _num(li.get("signal_dbm"))
    if link == "rear" and signal is None:
        signal = _num(doc.get("rssi_behind_dbm"))
    if signal is None:
        return None, origin
    return Reading(
        t,
        distance,
        signal,
        _num(li.get("tx_mbps")),
        _num(li.get("rx_mbps")),
        _num(li.get("ccq_pct")),
    ), origin


#: The share of the drive speed in the first `near_m` metres. L0 is the line's intercept
#: at 1 m, pinned by the readings of the first metres: at constant speed a 40 m drive
#: spends a tenth of its readings inside 4 m, and its L0 error (sd, sigma 6 dB) is about
#: 1 dB; a third of the speed there triples those readings and brings it to 0.7 dB, for
#: 40 s more (bench/RESULTS.md, calibration).
NEAR_SPEED_SHARE = 1.0 / 3.0
#: The default of `near_m` (--near-m).
NEAR_M = 4.0


@dataclass(frozen=True, slots=True)
class LiveOptions:
    url: str
    link: str = "rear"
    start_distance_m: float = 1.0
    hz: float = 4.0
    seconds: float = 120.0
    distance_m: float = 20.0
    drive: bool = False
    speed_mm_s: float = 150.0
    token: str | None = None
    #: --drive goes at NEAR_SPEED_SHARE of speed_mm_s while nearer the node than this (m).
    near_m: float = NEAR_M


#: Resend the drive command this often: well inside the daemon's 0.5 s dead-man time.
DRIVE_RESEND_S = 0.2
#: Reasons that end a --drive run: the daemon refused to move the robot.
STOP_REASONS = ("obstacle", "no_sip", "deadman", "shutdown")


class DaemonApi:
    """The two calls a live calibration makes of a running daemon: a command posted to its
    API (an HTTP error is a SourceError naming the path), and GET /status."""

    def __init__(self, session: aiohttp.ClientSession, base: str) -> None:
        self.session, self.base = session, base

    async def post(self, path: str, body: dict[str, Any]) -> None:
        async with self.session.post(self.base + path, json=body) as resp:
            if resp.status != 200:
                text = await resp.text()
                raise SourceError(f"{path}: HTTP {resp.status}: {text[:200]}")

    async def status(self) -> dict[str, Any]:
        async with self.session.get(self.base + "/status") as resp:
            if resp.status != 200:
                raise SourceError(f"/status: HTTP {resp.status}")
            doc = await resp.json()
        if not isinstance(doc, dict) or "pose" not in doc:
            raise SourceError(f"{self.base}/status is not a relayd status document")
        return doc


# Complexity: one polling loop with its stop conditions (distance, time, a lost daemon, a stall) side by side.
async def sample_live(opts: LiveOptions, *, progress: Any = None) -> tuple[list[Reading], str]:
    """Poll a running relayd (and with `drive`, move it) until the distance or time is reached.

    Returns the readings and why sampling ended. The daemon is left in hold mode after
    a --drive run, on every path out (including cancellation).
    """
    import aiohttp

    base = opts.url.rstrip("/")
    if "://" not in base:
        base = "http://" + base
    headers = {"Authorization": f"Bearer {opts.token}"} if opts.token else {}
    readings: list[Reading] = []
    origin: tuple[float, float] | None = None
    why = "time"
    timeout = aiohttp.ClientTimeout(total=3.0)
    async with aiohttp.ClientSession(timeout=timeout, headers=headers) as session:
        api = DaemonApi(session, base)
        post, status = api.post, api.status

        loop = asyncio.get_running_loop()
        start = loop.time()
        distance = opts.start_distance_m
        next_drive = start
        try:
            if opts.drive:
                await post("/api/mode", {"mode": "manual"})
            while True:
                now = loop.time()
                if now - start >= opts.seconds:
                    break
                if opts.drive and now >= next_drive:
                    speed = opts.speed_mm_s * (NEAR_SPEED_SHARE if distance < opts.near_m else 1.0)
                    await post("/api/drive", {"left_mm_s": speed, "right_mm_s": speed})
                    next_drive = now + DRIVE_RESEND_S
                doc = await status()
                reading, origin = status_reading(
                    doc, link=opts.link, origin=origin, start_distance_m=opts.start_distance_m
                )
                if reading is not None:
                    distance = reading.distance_m
                    readings.append(reading)
                    if progress is not None:
                        progress(reading)
                if opts.drive and doc.get("reason") in STOP_REASONS:
                    why = f"the daemon stopped the robot: {doc.get('reason')}"
                    break
                if (
                    origin is not None
                    and reading is not None
                    and reading.distance_m - opts.start_distance_m >= opts.distance_m
                ):
                    why = "distance"
                    break
                await asyncio.sleep(min(1.0 / opts.hz, DRIVE_RESEND_S if opts.drive else 1.0))
        finally:
            if opts.drive:
                # Hold, whatever happened: the dead-man time stops the wheels anyway, hold keeps them stopped.
                try:
                    await asyncio.shield(post("/api/mode", {"mode": "hold"}))
                except (aiohttp.ClientError, TimeoutError, SourceError):
                    why = why + " (could not set hold mode: the dead-man time stopped the wheels)"
    return readings, why
