"""A fork server for sweep runs: the simulator imported once per worker, a process per run.

A run is still a process of its own (relayd/sweep/child.py says why), but starting one
with `python -m relayd.sweep.child` imports the simulator, the daemon and their libraries
each time: about 0.4 s of CPU, near a tenth of a generated world's run. The server is a
single-threaded process that imports them once and then forks a child per request, which
runs `relayd.sweep.child.main` exactly as the command would, with its stdout and stderr
in a file. One request at a time, in JSON lines on stdin:

    {"spec": RUN.json, "out": OUT_DIR, "log": STDERR_FILE}

answered on stdout with `{"pid": P}` when the child is forked and `{"pid": P, "exit": C}`
when it has ended (C as subprocess's returncode: negative for a signal). The caller
(relayd/sweep/task.py) bounds the run's time and kills P when it is over. The server
dies with its worker (PR_SET_PDEATHSIG), ends at end of input, and each child dies with
the server.
"""

from __future__ import annotations

import json
import os
import sys
import traceback
from collections.abc import Sequence
from typing import Any, NoReturn

from relayd.sweep import child


def preload() -> None:
    """Import what a run imports (relayd.sweep.child.run's own imports)."""
    import relayd.cli.sim
    import relayd.runtime.logsetup
    import relayd.runtime.vtime
    import relayd.sim.runner
    import relayd.sim.scenario  # noqa: F401


def _answer(doc: dict[str, Any]) -> None:
    os.write(1, (json.dumps(doc) + "\n").encode())


def _run_child(req: dict[str, Any]) -> NoReturn:
    """In the forked child: the run, its output in req["log"]; never returns."""
    code = 1
    try:
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        log = os.open(req["log"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        os.dup2(log, 1)
        os.dup2(log, 2)
        os.environ["RELAYD_SWEEP_PARENT_PID"] = str(os.getppid())
        code = child.main([str(req["spec"]), str(req["out"])])
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    except BaseException:  # noqa: BLE001 - whatever the run raised is its failure
        traceback.print_exc()
        code = 1
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:  # noqa: BLE001 - nothing left to tell it to
                pass
        os._exit(code)


def serve() -> int:
    child.die_with_parent()
    preload()
    for line in sys.stdin.buffer:
        if not line.strip():
            continue
        req = json.loads(line)
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            _run_child(req)
        _answer({"pid": pid})
        _, status = os.waitpid(pid, 0)
        _answer({"pid": pid, "exit": os.waitstatus_to_exitcode(status)})
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    if list(sys.argv[1:] if argv is None else argv):
        print("usage: python -m relayd.sweep.forkserver (requests on stdin)", file=sys.stderr)
        return 2
    return serve()


if __name__ == "__main__":
    sys.exit(main())
