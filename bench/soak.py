"""Soak: a long simulated convoy with a fault injected every minute (fault tolerance over time; not in CI).

Runs the `convoy` scenario in `relayd.sim.runner.SimRunner` (real daemons on fake
devices, one shared clock at `--speed`) for `--minutes` of wall time, kept going past
the scenario's end, and every `--fault-every` wall seconds breaks one thing on one
relay, in turn, for a quarter of that interval:

    robot pty hang-up / return, servo pty hang-up / return, RSSI file frozen,
    rear AP down / up, airOS session expiry

At quiet points (the fault repaired and every device of every relay connected again)
it samples this process's resident memory (VmRSS from /proc/self/status, after a
gc) and the number of asyncio tasks. The first sample is taken after `--warmup`
seconds, the last at the end; the table compares their growth with the targets
(< 5 MB, no task growth) and the exit status is 1 if either is missed or a relay did
not recover from a fault. The simulator's own objects live in the same process; its
trace is kept short so that it does not count as growth.

    .venv/bin/python bench/soak.py --minutes 2 --speed 10
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import inspect
import sys
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from relayd.runtime.logsetup import StdStream, setup_logging
from relayd.sim.relay import SimRelay
from relayd.sim.runner import SimRunner
from relayd.sim.scenario import load_scenario

RSS_GROWTH_TARGET_KB = 5 * 1024
#: How long after a repair the relay has to be whole again (wall seconds, generous).
RECOVER_TIMEOUT_S = 60.0


def vm_rss_kb() -> int:
    """This process's resident set size (kB), as the kernel reports it."""
    with open("/proc/self/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("no VmRSS in /proc/self/status")


def task_count() -> int:
    return len(asyncio.all_tasks())


class _FrozenProcfs:
    """Stands in for a relay's RSSI file writer while the file is frozen: writes nothing."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.path = inner.path

    def write(self, *args: Any, **kwargs: Any) -> None:
        return None


@dataclass
class Fault:
    name: str
    apply: Callable[[SimRelay], object]  # may return an awaitable
    undo: Callable[[SimRelay], object] | None


def _freeze(r: SimRelay) -> None:
    r.procfs = _FrozenProcfs(r.procfs)


def _thaw(r: SimRelay) -> None:
    if isinstance(r.procfs, _FrozenProcfs):
        r.procfs = r.procfs.inner


FAULTS = [
    Fault("robot pty hang-up", lambda r: r.robot.hang_up(), lambda r: r.robot.reappear()),
    Fault("servo pty hang-up", lambda r: r.maestro.hang_up(), lambda r: r.maestro.reappear()),
    Fault("RSSI frozen", _freeze, _thaw),
    Fault("rear AP down", lambda r: r.rear.set_down(True), lambda r: r.rear.set_down(False)),
    Fault("airOS session expiry", lambda r: r.rear.expire_sessions(), None),
]


@dataclass
class Sample:
    t: float
    rss_kb: int
    tasks: int


@dataclass
class Report:
    faults: list[tuple[str, str, float | None]] = field(default_factory=list)
    samples: list[Sample] = field(default_factory=list)
    snapshots: list[tracemalloc.Snapshot] = field(default_factory=list)


async def _maybe(value: object) -> None:
    if inspect.isawaitable(value):
        await value


def _whole(relays: list[SimRelay]) -> bool:
    """Every device of every relay connected and its data flowing."""
    for r in relays:
        st = r.daemon.state
        health = st.health_now()
        if not all(h.connected for h in health.values()) or len(health) < 5:
            return False
        if r.daemon.monitor is None or r.daemon.monitor.age_s(r.daemon.clock.now()) is None:
            return False
        if r.daemon.monitor.age_s(r.daemon.clock.now()) > 1.0:
            return False
    return True


async def _until_whole(relays: list[SimRelay], timeout_s: float) -> float | None:
    """Wall seconds until every relay is whole, or None on timeout."""
    t0 = time.monotonic()
    try:
        async with asyncio.timeout(timeout_s):
            while not _whole(relays):
                await asyncio.sleep(0.05)
    except TimeoutError:
        return None
    return time.monotonic() - t0


async def _sample(report: Report, t0: float) -> Sample:
    gc.collect()
    # The fewest tasks over a second: a request being served or a reconnect in flight is
    # not growth, a leaked task is there at every look.
    tasks = []
    for _ in range(5):
        await asyncio.sleep(0.2)
        tasks.append(task_count())
    s = Sample(time.monotonic() - t0, vm_rss_kb(), min(tasks))
    report.samples.append(s)
    if tracemalloc.is_tracing():
        snap = tracemalloc.take_snapshot()
        report.snapshots[1:] = [snap]
        if not report.snapshots:
            report.snapshots.append(snap)
    return s


async def soak(
    minutes: float, speed: float, fault_every_s: float, warmup_s: float, seed: int
) -> Report:
    scenario = load_scenario("convoy")
    # Keep the convoy running past the leader's goal for the whole soak.
    scenario = scenario.model_copy(update={"settle_after_goal_s": 1e9})
    ready = asyncio.Event()
    runner: SimRunner

    def trim(_rec: dict[str, Any]) -> None:
        # The trace would grow by 10 records per clock second: keep only the newest. The
        # fakes log every command and byte they receive for tests to inspect; those logs
        # are the harness's, not relayd's, so they are emptied too.
        if len(runner.records) > 50:
            del runner.records[:-1]
        for r in runner.relays:
            r.robot.commands.clear()
            r.maestro.commands.clear()
            del r.maestro.received[:], r.maestro.sent[:]

    runner = SimRunner(
        scenario,
        speed=speed,
        seed=seed,
        seconds=1e9,
        on_progress=trim,
        on_ready=lambda _ports: ready.set(),
    )
    report = Report()
    t0 = time.monotonic()
    end = t0 + minutes * 60.0
    sim = asyncio.create_task(runner.run(), name="soak-sim")
    try:
        async with asyncio.timeout(60.0):
            await ready.wait()
        if await _until_whole(runner.relays, RECOVER_TIMEOUT_S) is None:
            raise RuntimeError("the relays never came up whole")
        await asyncio.sleep(max(0.0, t0 + warmup_s - time.monotonic()))
        await _until_whole(runner.relays, RECOVER_TIMEOUT_S)
        first = await _sample(report, t0)
        print(
            f"[{first.t:6.0f} s] warm: {first.rss_kb / 1024:.1f} MB, {first.tasks} tasks",
            flush=True,
        )
        i = 0
        next_fault = time.monotonic()
        while next_fault + fault_every_s <= end:
            await asyncio.sleep(max(0.0, next_fault - time.monotonic()))
            fault = FAULTS[i % len(FAULTS)]
            relay = runner.relays[i % len(runner.relays)]
            await _maybe(fault.apply(relay))
            await asyncio.sleep(fault_every_s / 4.0)
            st = relay.daemon.state
            during = f"{st.state}/{st.reason}, wheels {st.wheels_left_mm_s:.0f}/{st.wheels_right_mm_s:.0f}"
            if fault.undo is not None:
                await _maybe(fault.undo(relay))
            recovered = await _until_whole(runner.relays, RECOVER_TIMEOUT_S)
            report.faults.append((fault.name, relay.name, recovered))
            s = await _sample(report, t0)
            rec = "NOT recovered" if recovered is None else f"whole again after {recovered:.1f} s"
            print(
                f"[{s.t:6.0f} s] {fault.name} on {relay.name} ({during}): {rec}; "
                f"{s.rss_kb / 1024:.1f} MB, {s.tasks} tasks",
                flush=True,
            )
            if sim.done():
                raise RuntimeError(f"the simulation ended early: {sim.exception()!r}")
            i += 1
            next_fault += fault_every_s
        await asyncio.sleep(max(0.0, end - time.monotonic()))
        await _until_whole(runner.relays, RECOVER_TIMEOUT_S)
        await _sample(report, t0)
    finally:
        sim.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await sim
    return report


def table(report: Report, args: argparse.Namespace) -> tuple[str, bool]:
    first, last = report.samples[0], report.samples[-1]
    growth_kb = last.rss_kb - first.rss_kb
    task_growth = last.tasks - first.tasks
    recovered = all(r is not None for _, _, r in report.faults)
    worst = max((r for _, _, r in report.faults if r is not None), default=None)
    rows = [
        (
            "resident memory (VmRSS)",
            f"{first.rss_kb / 1024:.1f} MB",
            f"{last.rss_kb / 1024:.1f} MB",
            f"{growth_kb / 1024:+.2f} MB",
            "< 5 MB",
            growth_kb < RSS_GROWTH_TARGET_KB,
        ),
        (
            "asyncio tasks",
            str(first.tasks),
            str(last.tasks),
            f"{task_growth:+d}",
            "no growth",
            task_growth <= 0,
        ),
        (
            "faults recovered",
            "",
            f"{sum(r is not None for _, _, r in report.faults)}/{len(report.faults)}",
            "" if worst is None else f"worst {worst:.1f} s",
            "all",
            recovered,
        ),
    ]
    out = [
        f"soak: convoy, {args.minutes:g} min wall at speed {args.speed:g}, a fault every "
        f"{args.fault_every:g} s ({len(report.faults)} injected); samples after {first.t:.0f} s "
        f"and {last.t:.0f} s",
        "",
        "| figure | after warm-up | at the end | growth | target | ok |",
        "|---|---|---|---|---|---|",
    ]
    out += [
        f"| {a} | {b} | {c} | {d} | {e} | {'yes' if ok else 'NO'} |" for a, b, c, d, e, ok in rows
    ]
    return "\n".join(out), all(ok for *_, ok in rows)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    p.add_argument("--minutes", type=float, default=60.0, help="wall minutes to run (default 60)")
    p.add_argument("--speed", type=float, default=10.0, help="simulation clock speed (default 10)")
    p.add_argument(
        "--fault-every", type=float, default=60.0, help="wall seconds between faults (default 60)"
    )
    p.add_argument(
        "--warmup",
        type=float,
        default=None,
        help="wall seconds before the first sample (default: 60, at most a quarter of the run)",
    )
    p.add_argument("--seed", type=int, default=1)
    p.add_argument(
        "--tracemalloc",
        type=int,
        default=0,
        metavar="N",
        help="also print the N source lines whose allocations grew most (slow)",
    )
    args = p.parse_args(argv)
    if args.warmup is None:
        args.warmup = min(60.0, args.minutes * 60.0 / 4.0)
    setup_logging("error", "console", StdStream("stderr"))
    if args.tracemalloc:
        tracemalloc.start(1)
    report = asyncio.run(soak(args.minutes, args.speed, args.fault_every, args.warmup, args.seed))
    text, ok = table(report, args)
    print(text)
    if len(report.snapshots) == 2:
        print(f"\nallocation growth, top {args.tracemalloc}:")
        diff = report.snapshots[1].compare_to(report.snapshots[0], "lineno")
        for stat in diff[: args.tracemalloc]:
            print(f"  {stat.size_diff / 1024:+9.1f} kB {stat.count_diff:+7d} blocks")
            for line in stat.traceback.format()[-2:]:
                print("      " + line)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
