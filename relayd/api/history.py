"""The last minutes of one relay, kept by the daemon so a reloaded page still has them.

A bounded ring of samples taken every `period_s` from the status snapshot (the same
document /status serves): RSSI^l, RSSI^b, bearing, drive state and odometry pose.
It only reads the snapshot; nothing else in the daemon knows it exists. Served at
GET /history?after=SEQ as columns, oldest first, with each sample's age relative to
the answer, so a page needs no clock agreement with the robot. A page asks once for
everything (after=-1), then only for samples newer than the last it holds; an `after`
from a previous run of the daemon (beyond the newest sequence number) gets the whole
buffer again, and the page sees from the sequence numbers that it must start over.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections import deque
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from typing import Any

import structlog
from aiohttp import web

from drivers.transport.clock import Clock

log = structlog.get_logger(__name__)

#: Five minutes at 2 Hz: fine enough for a pose trail at walking speed (0.2 m apart at
#: 400 mm/s) and a few tens of kilobytes for a page that reloads over the relayed link.
DEFAULT_PERIOD_S = 0.5
DEFAULT_WINDOW_S = 300.0
#: The columns of a sample, in /history order (besides seq and age_s).
FIELDS = ("rssi_leader_dbm", "rssi_behind_dbm", "bearing_deg", "state", "x_mm", "y_mm", "theta_deg")


@dataclass(frozen=True, slots=True)
class Sample:
    seq: int
    t: float
    values: tuple[Any, ...]  # in FIELDS order


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def sample_values(doc: dict[str, Any]) -> tuple[Any, ...]:
    """The FIELDS of one status document (missing or non-finite numbers become None)."""
    pose = doc.get("pose") or {}
    return (
        _finite(doc.get("rssi_leader_dbm")),
        _finite(doc.get("rssi_behind_dbm")),
        _finite(doc.get("bearing_deg")),
        doc.get("state"),
        _finite(pose.get("x_mm")),
        _finite(pose.get("y_mm")),
        _finite(pose.get("theta_deg")),
    )


class History:
    """Ring buffer of status samples; `sample()` on a timer, `window()` for the endpoint."""

    def __init__(
        self,
        snapshot: Callable[[float], dict[str, Any]],
        clock: Clock,
        *,
        period_s: float = DEFAULT_PERIOD_S,
        window_s: float = DEFAULT_WINDOW_S,
    ) -> None:
        if period_s <= 0 or window_s < period_s:
            raise ValueError("history needs period_s > 0 and window_s >= period_s")
        self._snapshot = snapshot
        self.clock = clock
        self.period_s = period_s
        self.window_s = window_s
        self.samples: deque[Sample] = deque(maxlen=math.ceil(window_s / period_s))
        self.next_seq = 0
        self._thresholds: dict[str, Any] = {}

    def sample(self) -> None:
        now = self.clock.now()
        doc = self._snapshot(now)
        self._thresholds = dict(doc.get("thresholds") or {})
        self.samples.append(Sample(self.next_seq, now, sample_values(doc)))
        self.next_seq += 1

    async def run(self) -> None:
        """Sample forever; a broken snapshot costs one sample and a log line, not the task."""
        while True:
            try:
                self.sample()
            except Exception:  # a reader must never die of what it reads
                log.exception("history_sample_failed")
            await self.clock.sleep(self.period_s)

    def window(self, after: int) -> dict[str, Any]:
        """Samples with seq > after (all of them when `after` is from the future)."""
        now = self.clock.now()
        if after >= self.next_seq:
            after = -1
        chosen = [s for s in self.samples if s.seq > after]
        columns: dict[str, list[Any]] = {
            "seq": [s.seq for s in chosen],
            "age_s": [round(max(0.0, now - s.t), 3) for s in chosen],
        }
        for i, name in enumerate(FIELDS):
            columns[name] = [s.values[i] for s in chosen]
        return {
            "period_s": self.period_s,
            "window_s": self.window_s,
            "next_seq": self.next_seq,
            "thresholds": self._thresholds,
            "samples": columns,
        }


HISTORY: web.AppKey[History] = web.AppKey("relayd_history", History)


def parse_after(raw: str | None) -> int:
    """The `after` query parameter: an integer >= -1 (default -1, everything)."""
    if raw is None or raw == "":
        return -1
    try:
        value = int(raw)
    except ValueError:
        raise ValueError(f"after must be an integer, got {raw[:40]!r}") from None
    if value < -1:
        raise ValueError("after must be >= -1")
    return value


def install(
    app: web.Application, history: History, respond: Callable[[Any, int], web.Response]
) -> None:
    """Register GET /history on `app` and run the sampler while the app runs."""
    app[HISTORY] = history

    async def handle_history(request: web.Request) -> web.Response:
        try:
            after = parse_after(request.query.get("after"))
        except ValueError as exc:
            return respond({"error": str(exc), "field": "after"}, 400)
        return respond(request.app[HISTORY].window(after), 200)

    async def sampler(app: web.Application) -> AsyncIterator[None]:
        task = asyncio.create_task(app[HISTORY].run(), name="api-history")
        yield
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task

    app.router.add_get("/history", handle_history)
    app.cleanup_ctx.append(sampler)
