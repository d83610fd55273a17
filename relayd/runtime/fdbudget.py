"""One account of the file descriptors that every listener in the process holds.

The API, the live Foxglove view and whatever listens next share the process's
descriptor table with the device drivers. Each listener once guarded itself by the
number of the descriptor it was handed ("below the soft limit minus a reserve"): that
only holds while it is the one thing taking descriptors. Once another listener has
filled the table, the low numbers a device frees on a reconnect pass that check, the
listener takes them, and the device cannot reopen (EMFILE: the wheels stop).

`FdBudget` is the shared account: every listener asks it before keeping a connection
(`take`, with the descriptors the connection costs) and hands them back when the
connection ends (`give`). Together the listeners never hold more than `capacity`,
which leaves the devices their reserve whoever took the rest. The descriptor-number
check stays as a second guard (`admits`) for descriptors opened by anything else.
"""

from __future__ import annotations

import os
import resource
import threading

#: Descriptors kept free for the devices (serial ports, RSSI source, airOS sessions,
#: reconnects) whatever the listeners do; a quarter of the limit when that is smaller.
FD_RESERVE = 128


def fd_reserve(soft_limit: int) -> int:
    return min(FD_RESERVE, max(8, soft_limit // 4))


def soft_fd_limit() -> int:
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    return soft if soft != resource.RLIM_INFINITY else 1 << 20


def open_fds() -> int:
    """Descriptors open in this process now (0 where /proc cannot say)."""
    try:
        return len(os.listdir("/proc/self/fd"))
    except OSError:
        return 0


class FdBudget:
    """The descriptors listeners may hold between them (see the module docstring)."""

    def __init__(self, capacity: int, fd_limit: int) -> None:
        if capacity < 0:
            raise ValueError(f"capacity must be >= 0, got {capacity}")
        #: Descriptors all listeners together may hold.
        self.capacity = capacity
        #: A descriptor numbered at or above this is refused whoever holds the rest.
        self.fd_limit = fd_limit
        self.held: dict[str, int] = {}
        # Listeners may run on threads of their own (the live view's gate does).
        self._lock = threading.Lock()

    @classmethod
    def for_process(cls, soft_limit: int | None = None) -> FdBudget:
        """The budget of this process: its soft limit, less the devices' reserve, less what
        is open already (the interpreter, the logs, the listening sockets themselves)."""
        soft = soft_fd_limit() if soft_limit is None else soft_limit
        fd_limit = soft - fd_reserve(soft)
        return cls(max(0, fd_limit - open_fds()), fd_limit)

    @property
    def in_use(self) -> int:
        return sum(self.held.values())

    def admits(self, fileno: int) -> bool:
        return fileno < self.fd_limit

    def take(self, owner: str, n: int = 1) -> bool:
        """Book `n` descriptors for `owner`; False (nothing booked) when that would pass the capacity."""
        with self._lock:
            if sum(self.held.values()) + n > self.capacity:
                return False
            self.held[owner] = self.held.get(owner, 0) + n
            return True

    def give(self, owner: str, n: int = 1) -> None:
        with self._lock:
            left = self.held.get(owner, 0) - n
            if left < 0:
                raise ValueError(f"{owner} gives back {n} descriptor(s) it does not hold")
            self.held[owner] = left
