"""In-process stand-ins for the two devices that have no `memory://` link.

The simulator on virtual time needs every byte of device I/O to be a loop callback,
so that the same scenario and seed give the same run. The base and the servo
controller already have in-memory links (`drivers.transport.memlink`); these cover the rest:

- `MemoryRssi`: the Yagi adapter's RSSI as a real `drivers.wifi.RssiSource` (the same
  freshness and plausibility rules as the procfs source), fed by the world;
- `InProcessAirOs`: an `AirOsClient` whose status.cgi / sta.cgi documents come from a
  `FakeAirOs` object directly instead of over HTTP. The documents go through a JSON
  round trip and the client's own parsing, so the daemon sees exactly what it would
  see over the wire. The HTTP fake stays for the integration tests.
- `InProcessPath`: a relay following a relay reads its leader's GET /path from the
  leader's daemon in this process (its state's path source, the document the API
  serves), encoded as the API would, and parsed by the feed's own parser.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from drivers.airos.client import AirOsClient
from drivers.airos.fake import FakeAirOs
from drivers.airos.model import Station, parse_stations
from drivers.transport.clock import Clock
from drivers.wifi.sources import Observation, RssiSource


class MemoryRssi(RssiSource):
    """An RSSI source whose adapter is a variable; `write()` is one update, as ProcfsWriter's."""

    kind = "memory"

    def __init__(self, interface: str = "wlan1", *, clock: Clock) -> None:
        super().__init__(interface, clock=clock)
        self._level_dbm: float | None = None
        self._updates = 0

    def write(self, level_dbm: float) -> None:
        # Whole dBm, as the kernel reports them (and as ProcfsWriter writes them).
        self._level_dbm = float(round(level_dbm))
        self._updates += 1

    async def _observe(self) -> Observation:
        return Observation(self._level_dbm, self._updates, updated=self._level_dbm is not None)


def _wire(doc: Any) -> Any:
    """What the client would decode from the radio's answer."""
    return json.loads(json.dumps(doc))


class InProcessAirOs(AirOsClient):
    """An airOS client talking to a FakeAirOs object in this process (no sockets)."""

    def __init__(self, fake: FakeAirOs, *, clock: Clock, name: str) -> None:
        super().__init__(f"http://{name}.inproc", fake.username, "unused", firmware=6, clock=clock)
        self._fake = fake

    async def login(self) -> None:
        self.firmware = 6
        self.logged_in = True

    async def logout(self) -> None:
        self.logged_in = False

    async def close(self, logout_budget_s: float = 0.0) -> None:
        self.logged_in = False

    async def status(self) -> Any:
        return _wire(self._fake.status_doc)

    async def stations(self) -> tuple[Station, ...]:
        # The fake's own rule for what sta.cgi serves (its station list, or the link mirrored).
        return parse_stations(_wire(self._fake._station_list()))


class InProcessPath:
    """The leader relay's GET /path, read from its daemon here (a `PathClient`)."""

    def __init__(self, source: Callable[[], dict[str, Any] | None]) -> None:
        self._source = source
        self.alive = True

    def cut(self) -> None:
        """The bridge to the leader fails from now on (a test's or a bench's fault)."""
        self.alive = False

    async def fetch(self) -> bytes:
        if not self.alive:
            raise ConnectionError("the leader relay does not answer (cut)")
        doc = self._source()
        if doc is None:
            raise ConnectionError("the leader relay has no path source yet")
        return json.dumps(doc).encode()

    async def close(self) -> None:
        return None
