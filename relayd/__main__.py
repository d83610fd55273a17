"""`python -m relayd` and the `relayd` command: the command line, safe from an early Ctrl-C.

Importing the command line takes a few hundred milliseconds (pydantic, aiohttp). A Ctrl-C
in that time used to surface as a traceback: Python turns a KeyboardInterrupt raised
inside a class body's `__set_name__` into a RuntimeError, which no `except
KeyboardInterrupt` catches. So the interrupt is only noted while importing, and honoured
(exit 130) once the import is done.
"""

import signal
import sys
from types import FrameType


def entry() -> int:
    interrupted: list[int] = []

    def note(signum: int, _frame: FrameType | None) -> None:
        interrupted.append(signum)

    previous = signal.signal(signal.SIGINT, note)
    try:
        from relayd.cli import main
    finally:
        signal.signal(signal.SIGINT, previous)
    if interrupted:
        return 130
    try:
        return main()
    except KeyboardInterrupt:  # between the import and the command's own handlers
        return 130


if __name__ == "__main__":
    sys.exit(entry())
