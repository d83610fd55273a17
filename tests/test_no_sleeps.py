"""No test waits a fixed wall-clock time for something to happen.

A test that sleeps "long enough" is slow on an idle machine and flaky on a loaded one:
the machines that run the suite are shared, and 0.3 s is sometimes not enough. Tests wait
on the condition instead (`support.until`, an event, a log line), or run on virtual time
(`virtual_time`: a sleep there moves the loop's clock and takes no wall time).

This test reads every tests/*.py with `ast` and fails on an `asyncio.sleep(x)` or
`time.sleep(x)` that is not `sleep(0)` (a yield), not in a `virtual_time` test, module or
helper of one, and not in ALLOWED. An entry in ALLOWED names the file and function and
says why that sleep is not a wait for something to happen; its sleep line carries a `#`
comment (on it or just above it) saying the same in place.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

TESTS = Path(__file__).resolve().parent

#: (file, function qualname) -> why a sleep with a non-zero argument is right there.
ALLOWED: dict[tuple[str, str], str] = {
}


@dataclass(frozen=True)
class Sleep:
    file: str
    func: str
    line: int
    commented: bool

    def __str__(self) -> str:
        return f"tests/{self.file}:{self.line} in {self.func or '<module>'}"


def _mentions_virtual_time(node: ast.AST, aliases: set[str]) -> bool:
    return any((isinstance(n, ast.Attribute) and n.attr == "virtual_time")
               or (isinstance(n, ast.Name) and n.id in aliases) for n in ast.walk(node))


def _is_sleep(call: ast.Call, sleep_names: set[str]) -> bool:
    f = call.func
    if isinstance(f, ast.Attribute):
        return f.attr == "sleep" and isinstance(f.value, ast.Name) and f.value.id in ("asyncio", "time")
    return isinstance(f, ast.Name) and f.id in sleep_names


def _is_zero(call: ast.Call) -> bool:
    if not call.args:
        return False
    arg = call.args[0]
    return isinstance(arg, ast.Constant) and arg.value == 0


def _has_comment(lines: list[str], line: int) -> bool:
    here = lines[line - 1]
    above = lines[line - 2].strip() if line >= 2 else ""
    return "#" in here or above.startswith("#")


def wall_sleeps(path: Path) -> list[Sleep]:
    """The sleeps in `path` that may take wall time, with their enclosing function."""
    source = path.read_text()
    tree = ast.parse(source)
    lines = source.splitlines()
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

    def visit(node: ast.AST, qual: list[str], virtual: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                marked = any(_mentions_virtual_time(d, aliases) for d in child.decorator_list)
                visit(child, [*qual, child.name], virtual or marked)
                continue
            if (isinstance(child, ast.Call) and _is_sleep(child, sleep_names)
                    and not _is_zero(child) and not virtual):
                found.append(Sleep(path.name, ".".join(qual), child.lineno,
                                   _has_comment(lines, child.lineno)))
            visit(child, qual, virtual)

    visit(tree, [], module_virtual)
    return found


def _all_wall_sleeps() -> list[Sleep]:
    return [s for p in sorted(TESTS.glob("*.py")) for s in wall_sleeps(p)]


def test_no_fixed_wall_sleeps_outside_the_allowed_places() -> None:
    sleeps = _all_wall_sleeps()
    bad = [str(s) for s in sleeps if (s.file, s.func) not in ALLOWED]
    assert not bad, ("a fixed wall-clock sleep: wait on the condition (support.until), or run "
                     "the test on virtual time, or add it to ALLOWED with why:\n  " + "\n  ".join(bad))
    silent = [str(s) for s in sleeps if not s.commented]
    assert not silent, "an allowed sleep without a comment saying why:\n  " + "\n  ".join(silent)


def test_every_allowed_place_still_sleeps() -> None:
    """A stale entry would allow a new sleep there later without anyone deciding it."""
    used = {(s.file, s.func) for s in _all_wall_sleeps()}
    assert not set(ALLOWED) - used
    assert all(why.strip() for why in ALLOWED.values())
