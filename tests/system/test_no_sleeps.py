"""No test waits a fixed wall-clock time for something to happen.

A test that sleeps "long enough" is slow on an idle machine and flaky on a loaded one:
the machines that run the suite are shared, and 0.3 s is sometimes not enough. Tests wait
on the condition instead (`support.until`, an event, a log line), or run on virtual time
(a sleep there moves the loop's clock and takes no wall time).

This test reads every tests/*.py with `ast` and fails on an `asyncio.sleep(x)` or
`time.sleep(x)` that is not `sleep(0)` (a yield) and not on virtual time: in a test or
module marked `virtual_time`, or in a function run by `vtime.run`. What is left must be
in ALLOWED, which names the file and function and says why that sleep is not a wait for
something to happen (a poll interval, a fake's modelled delay, an injected fault's length).
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]

#: (file, function qualname) -> why a sleep with a non-zero argument is right there.
#: Keep it short: a new entry needs a reason that is not "it waits for something".
ALLOWED: dict[tuple[str, str], str] = {
    (
        "test_supervisor.py",
        "test_no_task_dying_keeps_wait_fatal_waiting_and_a_stop_is_not_fatal",
    ): "a span in which nothing may happen (no task dies, so wait_fatal must stay waiting)",
    (
        "test_run_signals.py",
        "test_ctrl_c_while_starting_exits_130_without_a_traceback",
    ): "the signal must land at a given moment of the child's start-up (its imports)",
    ("support.py", "until"): "the poll interval of the shared wait-for-a-condition helper",
    ("support.py", "until_sync"): "the same, for synchronous tests",
    ("rig_proc.py", "main.sample"): "the sampling period of the rig's wheel-speed sampler",
    (
        "test_reconnect.py",
        "Device.serve",
    ): "a fake device's session that lasts the seconds the test scripted",
    ("test_scanner.py", "ScriptedSource.read"): "a fake RSSI source's modelled read latency",
    (
        "test_serial_leaks.py",
        "test_hang_ups_idle_under_a_write_and_during_a_connect",
    ): "the injected fault: how long the cable stays pulled mid-connect; any outcome is then checked",
    (
        "test_systemd_unit.py",
        "_pet_periods",
    ): "waits out watchdog periods to see that no pet came; its one caller runs on virtual time",
    ("flood.py", "_slow_header"): "the slow-header attacker's pace: one byte a second",
    ("flood.py", "flood"): "how long the flood is held (its length is the load being applied)",
    (
        "test_live_page_ops.py",
        "test_stale_when_the_daemon_is_paused_or_killed",
    ): "watches a live page for 3 s of wall time to see it never goes stale (a span: the page's timers are wall time)",
    (
        "test_live_page_ops.py",
        "test_controls_reasons_history_and_layout",
    ): "the operator's drive refresh pace (a manual drive is re-sent every 0.15 s for 4 s)",
}


@dataclass(frozen=True)
class Sleep:
    file: str
    func: str
    line: int

    def __str__(self) -> str:
        return f"tests/{self.file}:{self.line} in {self.func or '<module>'}"


def _mentions_virtual_time(node: ast.AST, aliases: set[str]) -> bool:
    return any(
        (isinstance(n, ast.Attribute) and n.attr == "virtual_time")
        or (isinstance(n, ast.Name) and n.id in aliases)
        for n in ast.walk(node)
    )


def _is_sleep(call: ast.Call, sleep_names: set[str]) -> bool:
    f = call.func
    if isinstance(f, ast.Attribute):
        return (
            f.attr == "sleep"
            and isinstance(f.value, ast.Name)
            and f.value.id in ("asyncio", "time")
        )
    return isinstance(f, ast.Name) and f.id in sleep_names


def _is_zero(call: ast.Call) -> bool:
    if not call.args:
        return False
    arg = call.args[0]
    return isinstance(arg, ast.Constant) and arg.value == 0


def _runs_virtual(func: ast.AST) -> bool:
    """True if `func` calls `vtime.run(...)`: the coroutines it defines run on virtual time."""
    return any(
        isinstance(n, ast.Call)
        and isinstance(n.func, ast.Attribute)
        and n.func.attr == "run"
        and isinstance(n.func.value, ast.Name)
        and n.func.value.id == "vtime"
        for n in ast.walk(func)
    )


def wall_sleeps(path: Path) -> list[Sleep]:
    """The sleeps in `path` that may take wall time, with their enclosing function."""
    tree = ast.parse(path.read_text())
    # Names bound to the marker at module level (`VT = pytest.mark.virtual_time`), and
    # names under which a sleep function was imported (`from time import sleep`).
    aliases: set[str] = set()
    sleep_names: set[str] = set()
    module_virtual = False
    for stmt in tree.body:
        if isinstance(stmt, ast.Assign) and _mentions_virtual_time(stmt.value, set()):
            names = {t.id for t in stmt.targets if isinstance(t, ast.Name)}
            if "pytestmark" in names:
                module_virtual = True
            aliases |= names - {"pytestmark"}
        elif isinstance(stmt, ast.ImportFrom) and stmt.module in ("asyncio", "time"):
            sleep_names |= {a.asname or a.name for a in stmt.names if a.name == "sleep"}
    found: list[Sleep] = []

    def visit(node: ast.AST, qual: list[str], virtual: bool, inner_virtual: bool) -> None:
        # `inner_virtual`: functions defined here run on virtual time (under vtime.run).
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                marked = inner_virtual or any(
                    _mentions_virtual_time(d, aliases) for d in child.decorator_list
                )
                visit(child, [*qual, child.name], marked, marked or _runs_virtual(child))
                continue
            if (
                isinstance(child, ast.Call)
                and _is_sleep(child, sleep_names)
                and not _is_zero(child)
                and not virtual
            ):
                found.append(Sleep(path.name, ".".join(qual), child.lineno))
            visit(child, qual, virtual, inner_virtual)

    visit(tree, [], module_virtual, module_virtual)
    return found


def _all_wall_sleeps() -> list[Sleep]:
    return [s for p in sorted(TESTS.rglob("*.py")) for s in wall_sleeps(p)]


def test_no_fixed_wall_sleeps_outside_the_allowed_places() -> None:
    sleeps = _all_wall_sleeps()
    bad = [str(s) for s in sleeps if (s.file, s.func) not in ALLOWED]
    assert not bad, (
        "a fixed wall-clock sleep: wait on the condition (support.until), or run "
        "the test on virtual time, or add it to ALLOWED with why:\n  " + "\n  ".join(bad)
    )


def test_every_allowed_place_still_sleeps() -> None:
    """A stale entry would allow a new sleep there later without anyone deciding it."""
    used = {(s.file, s.func) for s in _all_wall_sleeps()}
    assert not set(ALLOWED) - used
    assert all(why.strip() for why in ALLOWED.values())


PROBE = """
import asyncio, time
import pytest
from asyncio import sleep as nap
from relayd.runtime import vtime

VT = pytest.mark.virtual_time

async def test_waits():
    await asyncio.sleep(0)
    await asyncio.sleep(0.3)
    time.sleep(x)
    await nap(1)

@VT
async def test_virtual():
    await asyncio.sleep(5)

@pytest.mark.virtual_time
class TestVirtual:
    async def test_it(self):
        await asyncio.sleep(5)

def test_runs_on_vtime():
    async def main():
        await asyncio.sleep(5)
    vtime.run(main())
    time.sleep(1)
"""


def test_the_scan_finds_wall_sleeps_and_passes_virtual_ones(tmp_path: Path) -> None:
    probe = tmp_path / "test_probe.py"
    probe.write_text(PROBE)
    found = [(s.func, s.line) for s in wall_sleeps(probe)]
    lines = PROBE.splitlines()
    want = [
        ("test_waits", lines.index("    await asyncio.sleep(0.3)") + 1),
        ("test_waits", lines.index("    time.sleep(x)") + 1),
        ("test_waits", lines.index("    await nap(1)") + 1),
        ("test_runs_on_vtime", lines.index("    time.sleep(1)") + 1),
    ]
    assert found == want
    (tmp_path / "test_marked.py").write_text(
        "import pytest, asyncio\n"
        "pytestmark = [pytest.mark.asyncio, pytest.mark.virtual_time]\n"
        "async def test_x():\n    await asyncio.sleep(3)\n"
    )
    assert wall_sleeps(tmp_path / "test_marked.py") == []
