"""The in-process event bus: one route from the device shells to the brain and to readers.

`publish(event)` does two things, in this order:

1. The *control path*: the brain's `handle(event)` runs synchronously, in publish
   order, and its actions go straight to the action handler (wheels, servo, state).
   Nothing queues between a SIP and the wheel command it causes, so no reader can
   make the control path lag.
2. The *fan-out*: every subscriber (a live view, a test) gets the event in its own
   bounded queue and reads it in its own task. A subscriber that must also see the
   decisions (the recorder) subscribes `with_actions` and gets `(event, actions)`
   pairs: the event and the actions the brain returned for it, as one item.

A slow subscriber never blocks the publisher: when its queue is full the **oldest**
queued event is dropped and counted in that subscriber's `dropped`. Decision:
drop-oldest, because every reader relayd has (live view, trace, recorder) cares about
the present more than about a backlog, and a reader that falls behind catches up on
current data instead of on ever older data. A reader that must see everything (a
recorder) sizes its queue for its worst pause and checks `dropped`.

Re-entrant publishing (an action handler publishing an event) is queued behind the
event being handled, so the brain always sees events one at a time, in order.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable, Sequence
from typing import Generic, TypeVar

E = TypeVar("E")
A = TypeVar("A")


class Subscription(Generic[E]):
    """One reader's bounded queue; `await get()` the next event, `dropped` counts losses."""

    __slots__ = ("_items", "_maxlen", "_waiter", "closed", "dropped", "name")

    def __init__(self, name: str, maxlen: int) -> None:
        if maxlen < 1:
            raise ValueError(f"subscription queue must hold at least 1 event, got {maxlen}")
        self.name = name
        self._maxlen = maxlen
        self._items: deque[E] = deque()
        self._waiter: asyncio.Future[None] | None = None
        self.dropped = 0
        self.closed = False

    def __len__(self) -> int:
        return len(self._items)

    def _put(self, event: E) -> None:
        if len(self._items) >= self._maxlen:
            self._items.popleft()
            self.dropped += 1
        self._items.append(event)
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def get_nowait(self) -> E | None:
        return self._items.popleft() if self._items else None

    async def get(self) -> E:
        while not self._items:
            if self.closed:
                raise EOFError(f"subscription {self.name!r} closed")
            self._waiter = asyncio.get_running_loop().create_future()
            try:
                await self._waiter
            finally:
                self._waiter = None
        return self._items.popleft()

    def close(self) -> None:
        self.closed = True
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)


class Bus(Generic[E, A]):
    """Publish events; the control path runs first and synchronously, then the fan-out."""

    def __init__(
        self,
        control: Callable[[E], Sequence[A]] | None = None,
        on_actions: Callable[[E, Sequence[A]], None] | None = None,
    ) -> None:
        self._control = control
        self._on_actions = on_actions
        self._subs: list[Subscription[E]] = []
        self._routed: list[Subscription[tuple[E, Sequence[A]]]] = []
        self._pending: deque[E] = deque()
        self._dispatching = False
        self.published = 0

    def connect(
        self, control: Callable[[E], Sequence[A]], on_actions: Callable[[E, Sequence[A]], None]
    ) -> None:
        """Set the control path (the brain) and where its actions go."""
        self._control = control
        self._on_actions = on_actions

    def subscribe(self, name: str, maxlen: int = 256) -> Subscription[E]:
        sub: Subscription[E] = Subscription(name, maxlen)
        self._subs.append(sub)
        return sub

    def subscribe_with_actions(
        self, name: str, maxlen: int = 256
    ) -> Subscription[tuple[E, Sequence[A]]]:
        """A subscription to each event together with the actions the brain returned for it."""
        sub: Subscription[tuple[E, Sequence[A]]] = Subscription(name, maxlen)
        self._routed.append(sub)
        return sub

    def unsubscribe(self, sub: Subscription[E] | Subscription[tuple[E, Sequence[A]]]) -> None:
        if sub in self._subs:
            self._subs.remove(sub)  # type: ignore[arg-type]
        if sub in self._routed:
            self._routed.remove(sub)  # type: ignore[arg-type]
        sub.close()

    def publish(self, event: E) -> None:
        self._pending.append(event)
        if self._dispatching:
            return  # handled, in order, by the publish call already running
        self._dispatching = True
        try:
            while self._pending:
                self._dispatch(self._pending.popleft())
        finally:
            self._dispatching = False

    def _dispatch(self, event: E) -> None:
        self.published += 1
        control, on_actions = self._control, self._on_actions
        actions: Sequence[A] = ()
        if control is not None:
            actions = control(event)
            if on_actions is not None:
                on_actions(event, actions)
        for sub in self._subs:
            sub._put(event)
        for routed in self._routed:
            routed._put((event, actions))
