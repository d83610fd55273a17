"""Event bus: the cost of one publish, side by side with 0, 1 and 3 subscribers.

What the control path pays per event on this host. Every configuration runs the same
brain (`relayd.core.brain.Brain` handling a real `SipEvent` every publish, so the row also
shows the bus's share next to a whole control step) and a no-op action handler. The
subscribers are real asyncio readers in their own tasks: "1" is one reader keeping up;
"3 + slow" adds a reader that keeps up and one that never reads (its bounded queue
fills and drops the oldest). Publishes come in bursts of 10 with a loop turn between
(readers run then), as SIPs, RSSI samples and ticks arrive on a robot. Time is
`time.perf_counter_ns()` around `publish()` alone; the figure is the median and p99
per publish over several thousand publishes.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Sequence

from bench.common import BenchOutput, Result, percentile
from drivers.arcos.sip import Sip
from relayd.core.brain import Brain, BrainParams
from relayd.core.events import Action, Event, SipEvent
from relayd.runtime.bus import Bus, Subscription

NAME = "bus"
#: A publish (with the brain's step) is on the SIP -> wheel command path: a tenth of its 2 ms budget.
TARGET_US = 200.0


def _sip(t: float) -> SipEvent:
    s = Sip(
        t=t,
        x_mm=0.0,
        y_mm=0.0,
        theta_deg=0.0,
        left_mm_s=0.0,
        right_mm_s=0.0,
        battery_v=13.0,
        motors_enabled=True,
        estop=False,
        stall_left=False,
        stall_right=False,
        moving=False,
        sonar=(),
    )
    return SipEvent(t, s, (None,) * 16)


async def _reader(sub: Subscription[Event], stuck: bool) -> None:
    if stuck:
        await asyncio.Event().wait()
    while True:
        await sub.get()


async def measure(subscribers: int, slow: bool, publishes: int) -> tuple[list[float], int]:
    bus: Bus[Event, Action] = Bus()
    brain = Brain(BrainParams(has_scanner=False))

    def on_actions(_e: Event, _a: Sequence[Action]) -> None:
        return None

    bus.connect(brain.handle, on_actions)
    subs = [bus.subscribe(f"r{i}", maxlen=256) for i in range(subscribers)]
    tasks = [
        asyncio.create_task(_reader(s, stuck=slow and i == len(subs) - 1))
        for i, s in enumerate(subs)
    ]
    samples: list[float] = []
    t = 0.0
    try:
        for _ in range(publishes // 10):
            for _ in range(10):
                t += 0.01
                ev = _sip(t)
                t0 = time.perf_counter_ns()
                bus.publish(ev)
                samples.append((time.perf_counter_ns() - t0) / 1000.0)
            await asyncio.sleep(0)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    dropped = sum(s.dropped for s in subs)
    return samples, dropped


def brain_only(publishes: int) -> list[float]:
    brain = Brain(BrainParams(has_scanner=False))
    out = []
    for i in range(publishes):
        ev = _sip(0.01 * (i + 1))
        t0 = time.perf_counter_ns()
        brain.handle(ev)
        out.append((time.perf_counter_ns() - t0) / 1000.0)
    return out


def run(quick: bool = False) -> BenchOutput:
    n = 2000 if quick else 20000
    out = BenchOutput(NAME)
    base = brain_only(n)
    out.results.append(
        Result(
            NAME,
            "brain.handle(SIP) alone, median (no bus)",
            percentile(base, 50),
            "us",
            "",
            None,
            f"p99 {percentile(base, 99):.1f} us",
        )
    )
    rows: list[tuple[str, int, bool]] = [
        ("0 subscribers", 0, False),
        ("1 subscriber", 1, False),
        ("3 subscribers, 1 never reads", 3, True),
    ]
    medians: dict[str, float] = {}
    for label, count, slow in rows:
        samples, dropped = asyncio.run(measure(count, slow, n))
        p50, p99 = percentile(samples, 50), percentile(samples, 99)
        medians[label] = p50
        out.results.append(
            Result(
                NAME,
                f"publish(SIP) incl. brain step, {label}: p99",
                p99,
                "us",
                f"< {TARGET_US:g} us",
                p99 < TARGET_US,
                f"median {p50:.1f} us; {dropped} events dropped by full queues",
            )
        )
    extra = medians["3 subscribers, 1 never reads"] - medians["0 subscribers"]
    out.details.append(
        f"Bus overhead over the bare brain step (median): {medians['0 subscribers'] - percentile(base, 50):.1f} us "
        f"with no subscriber; 3 subscribers (one stuck) add {extra:.1f} us more. A reader that never reads "
        "costs the publisher the same as one that keeps up: its queue drops the oldest event instead of growing."
    )
    return out


def main() -> None:
    o = run()
    for r in o.results:
        print(f"{r.figure:70s} {r.value_text():>10s}  {r.target:10s} {r.verdict():6s} {r.note}")
    for d in o.details:
        print(d)


if __name__ == "__main__":
    main()
