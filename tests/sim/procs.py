"""Processes by pid, from /proc: a test's own children and whether they are gone.

A process is named by (pid, start time) so a pid the kernel has handed to another
process since does not count as the old one still running, and by pid rather than by
name so tests running side by side (each with its own MobileSim) do not see each
other's. A zombie (exited, not yet reaped by whoever inherited it) is gone.
"""

from __future__ import annotations

import os
from pathlib import Path

Proc = tuple[int, int]  # (pid, start time in clock ticks since boot)


def _stat(pid: int) -> tuple[str, str, list[str]] | None:
    """(comm, state, the fields after the state) of /proc/PID/stat; None if there is none."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text(encoding="ascii", errors="replace")
    except OSError:
        return None
    # comm is in parentheses and may hold spaces or ')': split at the last one.
    head, _, tail = text.rpartition(")")
    fields = tail.split()
    return head.partition("(")[2], fields[0], fields[1:]


def children(parent: int) -> dict[str, Proc]:
    """The live children of `parent`, by command name (comm)."""
    out: dict[str, Proc] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (st := _stat(int(entry))) is not None:
            comm, state, rest = st
            # rest[0] is the parent's pid; the start time is field 22 of the line (rest[18]).
            if int(rest[0]) == parent and state != "Z":
                out[comm] = (int(entry), int(rest[18]))
    return out


def running(proc: Proc) -> bool:
    """Whether this very process (pid and start time) still runs (a zombie does not)."""
    st = _stat(proc[0])
    return st is not None and st[1] != "Z" and int(st[2][18]) == proc[1]


def started(pid: int) -> Proc:
    """(pid, start time) of a running process."""
    st = _stat(pid)
    assert st is not None, f"no process {pid}"
    return pid, int(st[2][18])
