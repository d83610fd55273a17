"""The live Foxglove server: control latency with one viewer connected vs none, side by side.

Latency: bench/latency.py's set-up (`relayd run` in its own process on a FakeRig, a
SIP every 25 ms that each causes a new wheel command: four times a robot's event
rate) with `[foxglove]` enabled in every round. Rounds alternate "no client" and "one
client" (bench/viewer.py in its own process, subscribed to every channel, reading
everything) in the same run, so both see the same machine. Figures: relayd's own
SIP -> wheel command histogram (the p99's bucket bound and the share within 2 ms) and
the end-to-end p99 taken in the fake's process; the viewer's message rate and its
worst lag (a message's log time to its arrival).

Loop cost: a bus with the real brain and the live server, fed one robot second's mix
of events (as bench/record.py's loop-cost row), the server's per-event work timed
with no client and with one client subscribed to every channel.
"""

from __future__ import annotations

import asyncio
import json
import time
from typing import Any

from bench.common import BenchOutput, Result, free_port, percentile
from bench.latency import measure

NAME = "foxglove"


async def _latency_rounds(rounds: int, cycles: int) -> list[tuple[bool, dict[str, Any]]]:
    out = []
    for _k in range(rounds):
        for viewer in (False, True):
            data = await measure(
                cycles=cycles, load_rps=0.0, foxglove_port=free_port(), viewer=viewer
            )
            out.append((viewer, {**data["alone"], "viewer": data["viewer"]}))
    return out


def _latency_rows(rounds: list[tuple[bool, dict[str, Any]]]) -> list[Result]:
    rows = []
    for viewer in (False, True):
        figs = [f for v, f in rounds if v is viewer]
        first = [x for f in figs for x in f["first_ms"]]
        inside = [f["in_relayd"] for f in figs]
        count = sum(i["count"] for i in inside)
        within = (
            sum((i["within_target"] or 0.0) * i["count"] for i in inside) / count if count else None
        )
        label = "one Foxglove client" if viewer else "no client"
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
                f"p50 {percentile(first, 50):.2f} ms, {len(first)} cycles; per round p50 "
                + ", ".join(f"{percentile(f['first_ms'], 50):.2f}" for f in figs)
                + " ms",
            )
        )
        cpu = [f["cpu_pct"] for f in figs]
        rows.append(
            Result(
                NAME,
                f"relayd CPU (its whole process), {label}",
                sum(cpu) / len(cpu),
                "% of a core",
                "",
                None,
                "per round " + ", ".join(f"{c:.1f}" for c in cpu) + " %",
            )
        )
    views = [f["viewer"] for v, f in rounds if v and f.get("viewer")]
    if views:
        rate = sum(v["messages"] for v in views) / max(1e-9, sum(v["seconds"] for v in views))
        kbps = sum(v["bytes"] for v in views) / max(1e-9, sum(v["seconds"] for v in views)) / 1e3
        rows.append(
            Result(
                NAME,
                "what the client received",
                rate,
                "messages/s",
                "",
                None,
                f"{kbps:.0f} kB/s on {views[0]['channels']} channels; worst lag "
                f"{max(v['lag_max_ms'] for v in views):.0f} ms (log time to arrival)",
            )
        )
    return rows


async def _loop_cost(events: int, with_client: bool) -> tuple[float, float, int]:
    """(median, p99) microseconds of loop time per event, and messages sent."""
    import aiohttp

    from drivers.arcos.sip import Sip
    from drivers.wifi.records import RssiSample
    from relayd.config.load import parse_settings
    from relayd.core.events import Action, Event, RssiEvent, ScanSampleEvent, SipEvent, Tick
    from relayd.record.live import SUBPROTOCOL, LiveServer
    from relayd.record.replay import make_brain
    from relayd.runtime.bus import Bus

    class Clock:
        t = 1000.0

        def now(self) -> float:
            return self.t

    samples: list[float] = []
    if True:
        settings = parse_settings(
            {"control": {"rear_link": "ignore"}, "foxglove": {"enabled": True, "port": 0}}
        )
        bus: Bus[Event, Action] = Bus()
        brain = make_brain(settings)
        bus.connect(brain.handle, lambda _e, _a: None)
        clock = Clock()
        # drain_s 0: a drain per loop turn, so this tight loop cannot overflow the queue.
        live = LiveServer(bus, settings, clock, drain_s=0.0)  # type: ignore[arg-type]
        take = live._take

        def timed(item: Any, topics: set[str]) -> None:
            t0 = time.perf_counter_ns()
            take(item, topics)
            samples.append((time.perf_counter_ns() - t0) / 1000.0)

        live._take = timed  # type: ignore[method-assign]
        live.start()
        task = asyncio.create_task(live.run())
        session = aiohttp.ClientSession()
        ws = None
        reader = None
        try:
            if with_client:
                ws = await session.ws_connect(
                    f"ws://127.0.0.1:{live.port}/", protocols=[SUBPROTOCOL], max_msg_size=0
                )
                ids = list(live.channel_ids().values())
                await ws.send_str(
                    json.dumps(
                        {
                            "op": "subscribe",
                            "subscriptions": [{"id": cid, "channelId": cid} for cid in ids],
                        }
                    )
                )
                while not all(ch.has_sinks() for ch in live._by_topic.values()):
                    await asyncio.sleep(0.01)

                async def drain() -> None:
                    assert ws is not None
                    async for _msg in ws:
                        pass

                reader = asyncio.create_task(drain())
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
        finally:
            if reader is not None:
                reader.cancel()
            if ws is not None:
                await ws.close()
            await session.close()
            live.close()
            await task
    return percentile(samples, 50), percentile(samples, 99), live.sent


def run(quick: bool = False) -> BenchOutput:
    out = BenchOutput(NAME)
    n = 2000 if quick else 20000
    for with_client in (False, True):
        med, p99, sent = asyncio.run(_loop_cost(n, with_client))
        label = "one client subscribed to every channel" if with_client else "no client"
        out.results.append(
            Result(
                NAME,
                f"event-loop time the live server takes per event, {label}, median",
                med,
                "us",
                "",
                None,
                f"p99 {p99:.0f} us; {sent} messages sent for {n} events "
                "(off the SIP path: after publish() returns)",
            )
        )
    rounds = asyncio.run(_latency_rounds(1 if quick else 4, 300 if quick else 800))
    out.results += _latency_rows(rounds)
    out.details.append(
        "Latency rounds alternate no client and one client (800 cycles each, a SIP every 25 ms, no /status "
        "load), the live server on in both, so both see the same machine; the share of commands within 2 ms "
        "is pooled over the rounds. The client is bench/viewer.py in its own process, subscribed to every "
        "channel."
    )
    return out
