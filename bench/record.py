"""Recording: control latency with the recorder on and off, side by side, and file size per hour.

Latency: bench/latency.py's set-up (`relayd run` in its own process on a FakeRig, a
SIP every 25 ms that each causes a new wheel command, so the recorder handles four
times a robot's event rate) measured in rounds that alternate recording off and on
in the same run, so both see the same machine. The figure is relayd's own
SIP -> wheel command histogram (the p99's bucket bound and the share within 2 ms)
and the end-to-end p99 taken in the fake's process.

Size: one relay's daemon on the FakeRig at the default settings (25-sample scans over
180 degrees, RSSI at 20 Hz, a SIP every 100 ms, both airOS radios polled) driving
toward its leader on the real clock, recording to a temporary file; the finished
file's size over the clock time recorded, per hour. A second row takes the
simulator's convoy (two relays, virtual time, the scenario's own scan settings) for
the whole scenario.
"""

from __future__ import annotations

import asyncio
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.common import BenchOutput, Result, percentile
from bench.latency import measure
from relayd.sim.runner import scratch_root

NAME = "record"
TARGET_MB_H = 200.0


async def _latency_rounds(rounds: int, cycles: int) -> list[tuple[bool, dict[str, Any]]]:
    out = []
    with tempfile.TemporaryDirectory(prefix="relayd-bench-rec-") as tmp:
        for k in range(rounds):
            for on in (False, True):
                record = (
                    {"enabled": True, "path": str(Path(tmp) / f"round{k}.mcap")} if on else None
                )
                data = await measure(cycles=cycles, load_rps=0.0, record=record)
                out.append((on, data["alone"]))
    return out


async def _rig_size(seconds: float) -> tuple[float, float]:
    """(bytes, clock seconds) of one relay's recording at the default settings."""
    from relayd.config.load import parse_settings
    from relayd.daemon import Daemon
    from relayd.fakes.rig import FakeRig
    from relayd.record.reader import read_recording

    with tempfile.TemporaryDirectory(prefix="relayd-bench-size-", dir=scratch_root()) as tmp:
        rig = FakeRig(Path(tmp), leader_xy_m=(40.0, 3.0))
        async with rig:
            path = Path(tmp) / "size.mcap"
            doc = rig.config_doc(log={"level": "warning"})
            doc["record"] = {"enabled": True, "path": str(path)}
            daemon = Daemon(parse_settings(doc), env=rig.env)
            task = asyncio.create_task(daemon.run())
            await asyncio.sleep(seconds)
            task.cancel()
            try:
                await task
            except asyncio.CancelledError:
                pass
        rec = read_recording(path)
        span = rec.steps[-1].event.t - rec.steps[0].event.t
        return float(path.stat().st_size), span


def _sim_size(seconds: float | None) -> tuple[float, float, int]:
    """(bytes over all relays, simulated seconds, relays) of the convoy recorded."""
    from relayd.runtime import vtime
    from relayd.sim.runner import SimRunner
    from relayd.sim.scenario import load_scenario

    with tempfile.TemporaryDirectory(prefix="relayd-bench-sim-") as tmp:
        sc = load_scenario("convoy")
        runner = SimRunner(sc, speed=None, seconds=seconds, record_dir=Path(tmp))
        result = vtime.run(runner.run())
        files = list(Path(tmp).glob("*.mcap"))
        return (
            float(sum(f.stat().st_size for f in files)),
            float(result.summary["sim_seconds"]),
            len(files),
        )


def _latency_rows(rounds: list[tuple[bool, dict[str, Any]]]) -> list[Result]:
    rows = []
    for on in (False, True):
        figs = [f for o, f in rounds if o is on]
        first = [x for f in figs for x in f["first_ms"]]
        inside = [f["in_relayd"] for f in figs]
        count = sum(i["count"] for i in inside)
        within = (
            sum((i["within_target"] or 0.0) * i["count"] for i in inside) / count if count else None
        )
        label = "recording on" if on else "recording off"
        rows.append(
            Result(
                NAME,
                f"in relayd: SIP -> wheel command p99, {label}",
                max(i["p99_le_ms"] or 0.0 for i in inside),
                "ms (<= bucket)",
                "",
                None,
                f"{count} commands over {len(figs)} round(s), "
                + (
                    f"{within * 100:.2f} % within 2 ms; per round p99 <= "
                    + ", ".join(f"{i['p99_le_ms']:g}" for i in inside)
                    + " ms"
                    if within is not None
                    else "no samples"
                ),
            )
        )
        rows.append(
            Result(
                NAME,
                f"SIP -> first wheel cmd p99 end to end, {label}",
                percentile(first, 99),
                "ms",
                "",
                None,
                f"p50 {percentile(first, 50):.2f} ms, {len(first)} cycles",
            )
        )
    return rows


async def _loop_cost(events: int) -> tuple[float, float]:
    """(median, p99) microseconds of event-loop time the recorder spends per event.

    A bus with the real brain and the recorder, fed the mix of one robot second (SIP
    and tick at 10 Hz, RSSI at 20 Hz, a scan's samples): the recorder's `_take` (encode
    the event and its actions, the Foxglove views, batching) is timed per event.
    """
    from drivers.arcos.sip import Sip
    from drivers.wifi.records import RssiSample
    from relayd.config.load import parse_settings
    from relayd.core.events import Action, Event, RssiEvent, ScanSampleEvent, SipEvent, Tick
    from relayd.record.recorder import Recorder
    from relayd.record.replay import make_brain
    from relayd.runtime.bus import Bus

    class Clock:
        t = 1000.0

        def now(self) -> float:
            return self.t

    samples: list[float] = []
    with tempfile.TemporaryDirectory(prefix="relayd-bench-cost-") as tmp:
        settings = parse_settings(
            {
                "record": {"enabled": True, "path": str(Path(tmp) / "c.mcap")},
                "control": {"rear_link": "ignore"},
            }
        )
        bus: Bus[Event, Action] = Bus()
        brain = make_brain(settings)
        bus.connect(brain.handle, lambda _e, _a: None)
        clock = Clock()
        rec = Recorder(bus, settings, clock)  # type: ignore[arg-type]
        take = rec._take

        def timed(item: Any) -> None:
            t0 = time.perf_counter_ns()
            take(item)
            samples.append((time.perf_counter_ns() - t0) / 1000.0)

        rec._take = timed  # type: ignore[method-assign]
        rec.start()
        task = asyncio.create_task(rec.run())
        k = 0
        while len(samples) < events:
            clock.t += 0.05
            k += 1
            if k % 2 == 0:
                s = Sip(
                    t=clock.t,
                    x_mm=float(k),
                    y_mm=0.0,
                    theta_deg=0.0,
                    left_mm_s=200.0,
                    right_mm_s=200.0,
                    battery_v=12.8,
                    motors_enabled=True,
                    estop=False,
                    stall_left=False,
                    stall_right=False,
                    moving=True,
                    sonar=((k % 16, 2000),),
                )
                bus.publish(SipEvent(clock.t, s, (2000,) * 16))
                bus.publish(Tick(clock.t))
            bus.publish(RssiEvent(clock.t, RssiSample(clock.t, -55.0, True)))
            bus.publish(ScanSampleEvent(clock.t, float(k % 180 - 90), -55.0))
            await asyncio.sleep(0)
        await rec.close()
        await task
    return percentile(samples, 50), percentile(samples, 99)


def run(quick: bool = False) -> BenchOutput:
    out = BenchOutput(NAME)
    med, p99 = asyncio.run(_loop_cost(2000 if quick else 20000))
    out.results.append(
        Result(
            NAME,
            "event-loop time the recorder takes per event, median",
            med,
            "us",
            "",
            None,
            f"p99 {p99:.0f} us; encode the event and its actions, Foxglove views, batching "
            "(off the SIP path: after publish() returns)",
        )
    )
    rounds = asyncio.run(_latency_rounds(1 if quick else 4, 300 if quick else 800))
    out.results += _latency_rows(rounds)
    rig_s = 20.0 if quick else 120.0
    size, span = asyncio.run(_rig_size(rig_s))
    mb_h = size / span * 3600.0 / 1e6
    out.results.append(
        Result(
            NAME,
            "recording size per hour of robot time, one relay, default settings",
            mb_h,
            "MB/h",
            f"< {TARGET_MB_H:g} MB/h",
            mb_h < TARGET_MB_H,
            f"{size / 1e3:.0f} kB over {span:.0f} s on the FakeRig (real clock), lz4 chunks of 1 s",
        )
    )
    started = time.monotonic()
    sim_bytes, sim_s, relays = _sim_size(60.0 if quick else None)
    sim_mb_h = sim_bytes / max(1, relays) / sim_s * 3600.0 / 1e6
    out.results.append(
        Result(
            NAME,
            "recording size per hour of robot time, simulated convoy, per relay",
            sim_mb_h,
            "MB/h",
            f"< {TARGET_MB_H:g} MB/h",
            sim_mb_h < TARGET_MB_H,
            f"{relays} relays, {sim_s:.0f} s simulated in {time.monotonic() - started:.0f} s wall",
        )
    )
    out.details.append(
        "Latency rounds alternate recording off and on (800 cycles each, a SIP every 25 ms, no /status "
        "load), so both see the same machine; the share of commands within 2 ms is pooled over the rounds. "
        "Size rows: the finished file (summary included) over the clock time it covers."
    )
    return out
