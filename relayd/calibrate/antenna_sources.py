"""Where `relayd calibrate antenna` gets its sweeps: a recording, a running relayd, or a simulation.

- **A recording** (`--from FILE`, docs/RECORDING.md): `/scan/sample` (the servo's angle
  and the RSSI heard there), `/scan/done` (a sweep ended) and `/robot/sip` (the heading,
  for a relay turned in place between sweeps), in log-time order.
- **A running relayd** (`--url`): its `/status`, polled; each new `last_scan` is a sweep
  (its angles and RSSI), with `pose.theta_deg` the heading. Read-only: the relay should
  stand in hold mode, sweeping; with the adaptive window a confident relay sweeps narrow
  windows, so set `scan.window = "full"` for the calibration (DEPLOY.md says so).
- **A simulation** (`sweep_messages`): sweeps of a still relay hearing a node through a
  known pattern, with the simulator's fading and whole-dB readings, as a recording holds
  them: for the tests and the bench.
"""

from __future__ import annotations

import asyncio
import json
import math
import random
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from relayd.calibrate import synthetic
from relayd.calibrate.antenna import AntennaSample
from relayd.calibrate.sources import SourceError
from relayd.calibrate.sources import _num as _num


def samples_from_messages(messages: Iterable[tuple[str, dict[str, Any]]]) -> list[AntennaSample]:
    """Samples from (topic, message) pairs in time order, as a recording holds them."""
    heading: float | None = None
    sweep = 0
    in_sweep = False
    out: list[AntennaSample] = []
    for topic, doc in messages:
        if topic == "/robot/sip":
            th = _num((doc.get("sip") or {}).get("theta_deg"))
            if th is not None:
                heading = th
        elif topic == "/scan/done":
            if in_sweep:
                sweep += 1
                in_sweep = False
        elif topic == "/scan/sample":
            t, a, r = _num(doc.get("t")), _num(doc.get("angle_deg")), _num(doc.get("rssi_dbm"))
            if t is None or a is None or r is None:
                continue
            out.append(AntennaSample(t, heading or 0.0, a, r, sweep))
            in_sweep = True
    return out


def _recording(path: str) -> Iterable[tuple[str, dict[str, Any]]]:
    from relayd.record.reader import RecordingError, iter_messages

    try:
        messages = iter_messages(
            Path(path), frozenset({"/robot/sip", "/scan/sample", "/scan/done"})
        )
    except RecordingError as exc:
        raise SourceError(f"not a readable MCAP recording: {exc}") from None
    for topic, _t, data in messages:
        try:
            doc = json.loads(data)
        except (ValueError, RecursionError):
            continue  # one undecodable message loses one sample, not the calibration
        if isinstance(doc, dict):
            yield topic, doc


def samples_from_recording(path: str) -> list[AntennaSample]:
    """The scan samples of an MCAP recording (SourceError when there are none)."""
    out = samples_from_messages(_recording(path))
    if not out:
        raise SourceError(f"{path}: no scan samples (channel /scan/sample)")
    return out


def samples_from_status(
    doc: dict[str, Any], sweep: int, last_t: float | None
) -> tuple[list[AntennaSample], float | None]:
    """A /status document's last scan as samples, unless it is the one seen last (`last_t`)."""
    scan = doc.get("last_scan")
    if not isinstance(scan, dict):
        return [], last_t
    t = _num(scan.get("t"))
    if t is None or t == last_t:
        return [], last_t
    heading = _num((doc.get("pose") or {}).get("theta_deg")) or 0.0
    angles, rssi = scan.get("angles") or [], scan.get("rssi") or []
    out = [
        AntennaSample(t, heading, float(a), float(r), sweep)
        for a, r in zip(angles, rssi, strict=False)
        if _num(a) is not None and _num(r) is not None
    ]
    return out, t


async def sample_live(
    url: str, *, sweeps: int, seconds: float, hz: float = 2.0, progress: Any = None
) -> tuple[list[AntennaSample], str]:
    """Poll a running relayd's /status until `sweeps` new scans (or `seconds`); read-only."""
    import aiohttp

    base = url.rstrip("/")
    if "://" not in base:
        base = "http://" + base
    out: list[AntennaSample] = []
    last_t: float | None = None
    seen = 0
    why = "time"
    async with aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=3.0)) as session:
        loop = asyncio.get_running_loop()
        start = loop.time()
        while loop.time() - start < seconds:
            async with session.get(base + "/status") as resp:
                if resp.status != 200:
                    raise SourceError(f"/status: HTTP {resp.status}")
                doc = await resp.json()
            if not isinstance(doc, dict) or "pose" not in doc:
                raise SourceError(f"{base}/status is not a relayd status document")
            first = last_t is None
            new, last_t = samples_from_status(doc, seen, last_t)
            # The scan on show when sampling starts may be older than the set-up: skip it.
            if new and not first:
                out += new
                seen += 1
                if progress is not None:
                    progress(seen)
                if seen >= sweeps:
                    why = "sweeps"
                    break
            await asyncio.sleep(1.0 / hz)
    return out, why


def sweep_messages(
    gain: Callable[[float], float],
    *,
    seed: int,
    node_bearing_deg: float = 0.0,
    level_dbm: float = -45.0,
    sweeps_per_heading: int = 6,
    headings_deg: Sequence[float] = (0.0,),
    angles_deg: Sequence[float] | None = None,
    rician_k_db: float | None = 6.0,
    jitter_db: float = 1.0,
    multipath: tuple[float, float] | None = None,
) -> list[tuple[str, dict[str, Any]]]:
    """A simulated calibration as a recording's messages: a still relay, a node at
    `node_bearing_deg`, full sweeps (`angles_deg`, default 25 over +-90), at each heading
    of `headings_deg` (turned in place between them), `sweeps_per_heading` each.

    Each reading: `level_dbm` + gain(off axis) + Rician fading (K `rician_k_db`; None:
    Rayleigh) averaged over 4 frames as the simulator's adapter does, + uniform
    +-`jitter_db`, rounded to whole dB. `multipath` = (bearing, relative dB): a second
    path from that bearing (a reflection off something moving: a person walking a metre a
    second changes its length by 8 wavelengths a second, so its phase is new at every
    reading), added coherently: the unstable shape a calibration must refuse.
    """
    from relayd.sim.radio import Radio, RadioParams

    rng = random.Random(seed)
    k = rician_k_db if rician_k_db is not None else -60.0
    radio = Radio(RadioParams.outdoor(rician_k_db=k), [], seed=seed)
    angles = list(angles_deg) if angles_deg is not None else [-90 + 7.5 * i for i in range(25)]
    out: list[tuple[str, dict[str, Any]]] = []
    seq, t = 0, 0.0
    for heading in headings_deg:
        out.append(("/robot/sip", {"seq": seq, "t": t, "sip": {"t": t, "theta_deg": heading}}))
        seq += 1
        for _ in range(sweeps_per_heading):
            for a in angles:
                phase = rng.uniform(0.0, 2.0 * math.pi)
                t = round(t + 0.1, 6)
                off = math.remainder(node_bearing_deg - heading - a, 360.0)
                g = gain(off)
                if multipath is not None:
                    mb, mdb = multipath
                    g2 = gain(math.remainder(mb - heading - a, 360.0)) + mdb
                    amp = 10 ** (g / 20.0) + 10 ** (g2 / 20.0) * complex(
                        math.cos(phase), math.sin(phase)
                    )
                    g = 20.0 * math.log10(max(abs(amp), 1e-6))
                fade = radio.fading_db(rician_k_db is not None)
                r = level_dbm + g + fade + rng.uniform(-jitter_db, jitter_db)
                r = float(round(max(r, -95.0)))
                out.append(("/scan/sample", {"seq": seq, "t": t, "angle_deg": a, "rssi_dbm": r}))
                seq += 1
            out.append(("/scan/done", {"seq": seq, "t": t, "started_t": t, "samples": len(angles)}))
            seq += 1
    return out


def write_recording(path: str, messages: Sequence[tuple[str, dict[str, Any]]]) -> None:
    """An MCAP file with these messages (relayd's layout), for `--from`."""
    synthetic.write_recording(
        path,
        messages,
        {
            "/robot/sip": "relayd.SipEvent",
            "/scan/sample": "relayd.ScanSampleEvent",
            "/scan/done": "relayd.ScanDone",
        },
        "relayd calibrate antenna synthetic",
    )
