"""Suite-wide test rules: an async test may leave no task and no timer behind, no test
leaves its structlog configuration to the next; the longest files run first.

A task still running after its test (a driver's `run()` nobody cancelled, a fake's
SIP loop nobody stopped) or a timer still pending (a `call_later` nobody cancelled)
is a leak: in the daemon it would be a task that outlives a restart, and in the suite
it runs on into the next test and makes it fail for reasons of its own. Such a test
fails here, naming what it left; what it left is then cancelled so the next test
starts clean. Nothing is allowed: fix the leak instead.
"""

from __future__ import annotations

import asyncio
import inspect
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest
import pytest_asyncio
import structlog

#: The files that take longest, longest first: roughly seconds on an idle 2-core machine
#: (wall time where a file mostly waits, CPU time where it computes). scripts/test runs
#: the suite on pytest-xdist workers, one file at a time per worker (--dist loadfile),
#: handed out in collection order (--no-loadscope-reorder): with the long files first,
#: the last file to finish is a short one, instead of a 25 s one started last on one
#: worker while the other idles. A stale list costs only wall time; every file not named
#: runs after these, in their usual order.
LONGEST_FILES_FIRST = (
    "tests/sim/test_mobilesim.py",  # ~2.5 min where MobileSim is provisioned, waits: real time
    "tests/tools/test_sweep_dask.py",  # ~2-3 min, CPU: 50 worlds on a scheduler, then a LocalCluster
    "tests/system/test_types.py",  # ~15 s cold (a fresh checkout), CPU: mypy, strict
    "tests/api/test_flood.py",  # ~22 s, waits: a 13 s flood
    "tests/tools/test_sweep.py",  # ~25 s, Dask clusters and child processes
    "tests/record/test_foxglove.py",  # ~19 s, a 6 s stalled-client window, a virtual-time flood
    "tests/system/test_offline_install.py",  # ~20 s, pip against the index
    "tests/api/test_live_page_ops.py",  # ~18 s, waits: the page's stale timers
    "tests/sim/test_convoy_corridor.py",  # ~16 s, CPU: four paper scenarios
    "tests/bench/test_smoke.py",  # ~10 s, its four live benchmarks side by side
    "tests/drivers/test_fuzz_decoders.py",  # ~12 s, CPU: hypothesis
    "tests/core/link/test_model.py",  # ~12 s of CPU, hypothesis (third longest file on a loaded machine)
    "tests/sim/test_recovery.py",  # ~11 s, CPU: drift and door, recovery off and on
    "tests/sim/test_scenarios.py",  # ~10 s, CPU: the obstacle scenarios
    "tests/drivers/transport/test_serial_leaks.py",  # ~10 s, waits: pty hang-ups
    "tests/system/test_sigterm.py",
    "tests/api/test_tls.py",
    "tests/system/test_live_page_browser.py",
    "tests/api/test_schemathesis.py",
    "tests/core/avoid/test_escape.py",
    "tests/drivers/airos/test_model.py",
    "tests/record/test_record.py",
    "tests/core/recovery/test_machine.py",
    "tests/record/test_record_daemon.py",
    "tests/system/test_fleet_browser.py",
    "tests/system/test_bridge_netns.py",
)


ROOT = Path(__file__).resolve().parent.parent


def _relative(path: Path) -> str:
    try:
        return path.resolve().relative_to(ROOT).as_posix()
    except ValueError:
        return path.name


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Longest files first (see LONGEST_FILES_FIRST); a stable sort keeps each file's order."""
    rank = {name: i for i, name in enumerate(LONGEST_FILES_FIRST)}
    items.sort(key=lambda item: rank.get(_relative(item.path), len(rank)))


#: Turns of the loop given to things a test has just cancelled or closed, so their
#: callbacks (connection_lost, done-callbacks) can run before the check.
SETTLE_TURNS = 20


def _pending_timers(loop: asyncio.AbstractEventLoop) -> list[asyncio.TimerHandle]:
    # The base event loop keeps its timer heap in `_scheduled`; no public API lists it.
    scheduled: list[asyncio.TimerHandle] = getattr(loop, "_scheduled", [])
    return [h for h in scheduled if not h.cancelled()]


async def _settle() -> None:
    for _ in range(SETTLE_TURNS):
        await asyncio.sleep(0)


def leftovers(
    loop: asyncio.AbstractEventLoop,
) -> tuple[list[asyncio.Task[object]], list[asyncio.TimerHandle]]:
    """Tasks (other than the caller's) still running and timers still pending on `loop`."""
    current = asyncio.current_task(loop)
    tasks = [t for t in asyncio.all_tasks(loop) if t is not current and not t.done()]
    return tasks, _pending_timers(loop)


def describe(tasks: list[asyncio.Task[object]], timers: list[asyncio.TimerHandle]) -> str:
    parts = [f"task {t.get_name()}: {t.get_coro()!r}" for t in tasks]
    parts += [f"timer {h!r}" for h in timers]
    return "; ".join(parts)


async def _fail_on(
    tasks: list[asyncio.Task[object]], timers: list[asyncio.TimerHandle], where: str = ""
) -> None:
    """Fail the test naming what it left, after cancelling it so the next test starts clean."""
    if not (tasks or timers):
        return
    for t in tasks:
        t.cancel()
    for h in timers:
        h.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    pytest.fail(
        f"the test leaked {len(tasks)} task(s) and {len(timers)} timer(s){where}: "
        f"{describe(tasks, timers)}",
        pytrace=False,
    )


@pytest.fixture
async def _no_leaks_async() -> AsyncIterator[None]:
    loop = asyncio.get_running_loop()
    yield
    await _settle()
    await _fail_on(*leftovers(loop))


@pytest_asyncio.fixture(loop_scope="module")
async def _no_new_tasks_module() -> AsyncIterator[None]:
    """The check for a test on a module-wide loop (a daemon shared by the file's tests).

    The shared daemon's own tasks and timers live on between tests by design; what the
    test itself started must not. Timers are left out: the daemon re-arms its own.
    """
    loop = asyncio.get_running_loop()
    before = set(asyncio.all_tasks(loop))
    yield
    await _settle()
    await _fail_on([t for t in leftovers(loop)[0] if t not in before], [], " on its module's loop")


@pytest.fixture(autouse=True)
def _no_leaks(request: pytest.FixtureRequest) -> None:
    """Applies the leak check to every coroutine test (sync tests have no loop to leak on)."""
    func = getattr(request.node, "function", None)
    if func is None or not inspect.iscoroutinefunction(func):
        return
    marker = request.node.get_closest_marker("asyncio")
    loop_scope = marker.kwargs.get("loop_scope", "function") if marker is not None else "function"
    if loop_scope == "module":
        request.getfixturevalue("_no_new_tasks_module")
    elif loop_scope == "function":
        request.getfixturevalue("_no_leaks_async")
    else:
        pytest.fail(
            f"no leak check for loop_scope={loop_scope!r}: add one to tests/conftest.py",
            pytrace=False,
        )


@pytest.fixture(autouse=True)
def _structlog_restored() -> Iterator[None]:
    """Whatever structlog configuration a test leaves (a benchmark or command run in this
    process calls setup_logging, e.g. at level "error") is undone after it: otherwise a
    later test's capture_logs() misses warnings, depending on which file ran before it
    on the same worker."""
    before = structlog.get_config()
    yield
    structlog.configure(**before)


def pytest_asyncio_loop_factories(config: pytest.Config, item: pytest.Item) -> dict[str, object]:
    """A test marked `virtual_time` runs on the jumping loop; every other on a plain one."""
    from tests.support import VirtualTimeLoop

    if item.get_closest_marker("virtual_time") is not None:
        return {"virtual": VirtualTimeLoop}
    return {"asyncio": asyncio.new_event_loop}
