"""Poll one airOS radio forever and keep its latest link quality, state and counters.

The poller is the long-running task the daemon supervises: `run()` never raises except
`CancelledError`. Policy per failure class:

* session expired (redirect to login, 401/403, HTML answer): log in again at once, once;
  a second expiry straight after a fresh login backs off like a network error;
* network error / timeout: capped exponential backoff (drivers.transport.backoff), state "unreachable";
* malformed JSON / not a status document: counted, state "bad_data", log in again on the next
  try (an HTML or garbled answer is how an expired session looks, docs/PROTOCOLS.md 4.1:
  log in again once, then back off);
* wrong credentials: state "auth_failed", retried on the same capped backoff as any other
  failure: a password fixed on the radio is picked up within seconds, because the robot
  may be held until it is. Even at the cap that is one login a few seconds apart, which
  airOS does not lock out. The refusal is logged once, then once a minute while it lasts.

The loop itself is the shared `drivers.transport.reconnect.Reconnect.run` (backoff and log
discipline): a connection is a login and a first good poll, serving it is polling at a
fixed rate until a poll fails. A change of failure class is logged at WARNING as news.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import aiohttp
import structlog
from pydantic import SecretStr

from drivers.airos.client import (
    AirOsAuthError,
    AirOsClient,
    AirOsConnectionError,
    AirOsSessionExpired,
    AirOsTimeoutError,
    Firmware,
)
from drivers.airos.model import AirOsDataError, LinkQuality
from drivers.transport.backoff import Backoff
from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.transport.health import DeviceHealth, LinkState
from drivers.transport.reconnect import Failure, Reconnect

log = structlog.get_logger(__name__)

STATES = ("connecting", "ok", "unreachable", "auth_failed", "bad_data")


class AirOsPoller:
    """Keeps `latest` fresh at one poll every `poll_s` clock seconds."""

    def __init__(
        self,
        url: str,
        username: str,
        password: str | SecretStr,
        *,
        poll_s: float = 1.0,
        legacy_tls: bool = False,
        timeout_s: float = 2.0,
        clock: Clock = REAL_CLOCK,
        on_update: Callable[[LinkQuality], None] | None = None,
        firmware: Firmware = "auto",
        session: aiohttp.ClientSession | None = None,
        backoff: Backoff | None = None,
        remind_s: float = 60.0,
    ) -> None:
        if not poll_s > 0:
            raise ValueError(f"poll_s must be > 0, got {poll_s!r}")
        self.client = AirOsClient(
            url,
            username,
            password,
            firmware=firmware,
            legacy_tls=legacy_tls,
            timeout_s=timeout_s,
            clock=clock,
            session=session,
        )
        self.url = str(self.client.base_url)
        self.poll_s = poll_s
        self._clock = clock
        self._on_update = on_update
        # Capped low: while RSSI^b is unknown the relay may be held still (rear_link =
        # "require"), so a radio that is back must be noticed within seconds, and one
        # HTTP request every few seconds costs nothing on the bridge.
        self._backoff = backoff or Backoff(
            initial_s=min(1.0, poll_s), maximum_s=max(5.0, 4.0 * poll_s)
        )
        self._reconnect = Reconnect(
            log.bind(url=self.url),
            "airos_poll_failed",
            backoff=self._backoff,
            clock=clock,
            remind_s=remind_s,
            recovered_event="",
        )
        self.latest: LinkQuality | None = None
        self.state: str = "connecting"
        self.last_error: str | None = None
        self.last_update_t: float | None = None
        self.counters: dict[str, int] = {
            "polls": 0,
            "errors": 0,
            "logins": 0,
            "relogins": 0,
            "timeouts": 0,
            "bad_json": 0,
            "auth_failures": 0,
            "callback_errors": 0,
        }
        self._had_session = False
        self._expired_in_row = 0
        #: When the next poll is due while the link is healthy (fixed rate).
        self._next_t = 0.0
        # Never set: the poller stops by being cancelled (the daemon's shutdown).
        self._stop = asyncio.Event()

    def __repr__(self) -> str:
        return f"AirOsPoller(url={self.url!r}, username={self.client.username!r}, state={self.state!r})"

    def health(self) -> DeviceHealth:
        """The radio link's health now (see drivers.transport.health); `state` keeps the finer story."""
        if self.state == "ok":
            state = LinkState.UP
        elif self.state == "connecting":
            state = LinkState.CONNECTING
        else:
            state = LinkState.DOWN
        return DeviceHealth(
            device="ap",
            state=state,
            last_error=self.last_error,
            errors=self.counters["errors"],
            reconnects=self.counters["relogins"],
            last_rx_t=self.last_update_t,
            counters=self.counters,
        )

    def age_s(self) -> float | None:
        """Clock seconds since the last good poll, None before the first."""
        return None if self.last_update_t is None else self._clock.now() - self.last_update_t

    def is_fresh(self, max_age_s: float) -> bool:
        age = self.age_s()
        return age is not None and age <= max_age_s

    async def run(self) -> None:
        """Poll until cancelled; on cancel, log out and close the session."""
        try:
            await self._reconnect.run(
                self._first_poll,
                self._serve,
                stop=self._stop,
                describe=_describe,
                on_failure=self._failed,
            )
        finally:
            await self.close()

    async def close(self) -> None:
        try:
            async with self._clock.timeout(self.client.timeout_s + 1.0):
                await self.client.close()
        except (TimeoutError, AirOsConnectionError, aiohttp.ClientError) as exc:
            log.debug("airos_close_failed", url=self.url, error=str(exc))

    async def _first_poll(self) -> None:
        # A connection is a login (if the session needs one) and a first good poll.
        self._next_t = self._clock.now()
        await self._poll()

    async def _serve(self) -> None:
        # Fixed rate while healthy: the request's own latency is not added. A failed
        # poll raises, and the reconnect loop backs off.
        while True:
            self._next_t += self.poll_s
            now = self._clock.now()
            if self._next_t < now:
                self._next_t = now
            await self._clock.sleep(self._next_t - now)
            await self._poll()

    async def _poll(self) -> None:
        """One poll (login if needed, then fetch); raises what went wrong, counted."""
        while True:
            try:
                if not self.client.logged_in:
                    await self.client.login()
                    self.counters["logins"] += 1
                    if self._had_session:
                        self.counters["relogins"] += 1
                    self._had_session = True
                quality = await self.client.fetch()
                break
            except AirOsSessionExpired as exc:
                self._expired_in_row += 1
                self.client.logged_in = False
                if self._expired_in_row > 1:
                    raise _ExpiredAgain(f"session refused right after login: {exc}") from exc
                # Once: log in again at once (a new schedule starts with this poll).
                log.info("airos_session_expired", url=self.url, error=str(exc))
                self._next_t = self._clock.now()
            except AirOsAuthError:
                self.counters["auth_failures"] += 1
                raise
            except AirOsTimeoutError:
                self.counters["timeouts"] += 1
                raise
            except AirOsDataError:
                self.counters["bad_json"] += 1
                self.client.logged_in = (
                    False  # maybe an expired session: log in again, then back off
                )
                raise
        self._expired_in_row = 0
        self.counters["polls"] += 1
        self.latest = quality
        self.last_update_t = quality.t
        if self.state != "ok":
            log.info("airos_link_up", url=self.url, previous=self.state)
        self.state = "ok"
        self.last_error = None
        if self._on_update is not None:
            try:
                self._on_update(quality)
            except Exception:  # a consumer bug must not stop the polling
                self.counters["callback_errors"] += 1
                log.exception("airos_on_update_failed", url=self.url)

    def _failed(self, exc: Exception, failure: Failure, text: str) -> None:
        self.counters["errors"] += 1
        self.state = failure.kind or "unreachable"
        self.last_error = text


class _ExpiredAgain(Exception):
    """The radio refused a session it had just granted."""


def _describe(exc: Exception) -> Failure:
    """A failed poll's class: its state ("kind") and its log line."""
    if isinstance(exc, AirOsAuthError):
        return Failure(
            kind="auth_failed",
            event="airos_auth_failed",
            fields={"hint": "check the username and password"},
        )
    if isinstance(exc, AirOsConnectionError):  # timeouts included
        return Failure(kind="unreachable", event="airos_link_unreachable")
    if isinstance(exc, AirOsDataError | _ExpiredAgain):
        return Failure(kind="bad_data", event="airos_link_bad_data")
    # A long-running task must survive anything; a bug is logged with its traceback.
    return Failure(
        kind="unreachable",
        event="airos_poll_crashed",
        unexpected=True,
        text=f"{type(exc).__name__}: {exc}",
    )
