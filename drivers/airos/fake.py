"""FakeAirOs: an aiohttp server on loopback that behaves like an airOS 6 or airOS 8 radio.

It speaks the real login flows (see client.py) and serves a real status.cgi capture, or
live values for the simulator (`set_link`, `set_stations`) written into that capture's
shape with the radio's own units (ccq per-mille, rates as strings, rssi = signal + 96).

Answers that are not documented anywhere are marked UNVERIFIED: the v6 failed-login page
(the firmware shows its login page again), v8's 401 for bad credentials and for requests
without a session (python-airos treats 401/403 alike).

Failure switches for tests and the simulator: `expire_sessions()`, `slow_s`, `malformed`,
`await set_down(True/False)` (refuse new connections and cut kept-alive ones).
"""

from __future__ import annotations

import html
import json
import secrets
import ssl
from collections.abc import Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import structlog
from aiohttp import web

from drivers.airos.fakedocs import LOGIN_PAGE, load_fixture, rate_text, station_entry
from drivers.airos.model import RSSI_OFFSET_DB, Station
from drivers.transport.clock import REAL_CLOCK, Clock

log = structlog.get_logger(__name__)

_Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


@dataclass(slots=True)
class _Session:
    authed: bool = False
    csrf_id: str | None = None


class FakeAirOs:
    """An airOS radio on 127.0.0.1: `await start()` returns its base URL."""

    def __init__(
        self,
        username: str = "ubnt",
        password: str = "ubnt",
        *,
        fixture: str | Path | Mapping[str, Any] | None = None,
        version: int = 6,
        clock: Clock = REAL_CLOCK,
        host: str = "127.0.0.1",
        port: int = 0,
        ssl_context: ssl.SSLContext | None = None,
    ) -> None:
        if version not in (6, 8):
            raise ValueError(f"version must be 6 or 8, got {version!r}")
        self.username = username
        self._password = password
        self.version = version
        self.status_doc = load_fixture(fixture)
        self.stations: list[dict[str, Any]] | None = None  # None: mirror the link on an AP
        self._clock = clock
        self.host = host
        self.port = port
        self.ssl_context = ssl_context  # serve https (e.g. a TLS 1.0-only airOS 6 lighttpd)
        self.login_content_types: list[str] = []  # what POST /login.cgi bodies were sent as
        # What an airOS 5/6 radio answers at airOS 8's /api/auth: 404 here, UNVERIFIED on
        # real firmware (a redirect or a 403 page are as plausible; the client copes with all).
        self.v6_api_auth_status = 404
        self.slow_s = 0.0
        self.malformed = False
        self.down = False
        self.counters: dict[str, int] = {
            "requests": 0,
            "logins": 0,
            "failed_logins": 0,
            "status": 0,
            "sta": 0,
            "redirects": 0,
            "logouts": 0,
        }
        self._sessions: dict[str, _Session] = {}
        self._cookie_name = (
            "AIROS_SESSIONID" if version == 6 else f"AIROS_{secrets.token_hex(6).upper()}"
        )
        self._runner: web.AppRunner | None = None
        self._site: web.TCPSite | None = None
        self.base_url: str | None = None

    def __repr__(self) -> str:
        return (
            f"FakeAirOs(url={self.base_url!r}, version={self.version}, username={self.username!r})"
        )

    # -- live values -----------------------------------------------------------------------

    def set_link(
        self,
        signal_dbm: float,
        noise_dbm: float = -95,
        ccq_pct: float | None = None,
        tx_mbps: float | None = None,
        rx_mbps: float | None = None,
    ) -> None:
        """Write a link into status.cgi in the radio's units (ccq per-mille, rate strings)."""
        w = self.status_doc.setdefault("wireless", {})
        signal = round(signal_dbm)
        rssi = signal + RSSI_OFFSET_DB
        w["signal"] = signal
        w["rssi"] = rssi
        w["noisef"] = round(noise_dbm)
        chain = max(0, rssi)
        w["chainrssi"] = [chain, max(0, chain - 3), 0]
        w["chainrssimgmt"] = list(w["chainrssi"])
        w["chainrssiext"] = list(w["chainrssi"])
        if ccq_pct is not None:
            w["ccq"] = round(ccq_pct * 10)
        if tx_mbps is not None:
            w["txrate"] = rate_text(tx_mbps)
        if rx_mbps is not None:
            w["rxrate"] = rate_text(rx_mbps)

    def set_stations(self, stations: Iterable[Station | Mapping[str, Any]]) -> None:
        """Serve this station list on /sta.cgi (Station objects or raw wstalist dicts)."""
        out: list[dict[str, Any]] = []
        for i, s in enumerate(stations):
            out.append(station_entry(s, i) if isinstance(s, Station) else dict(s))
        self.stations = out
        w = self.status_doc.setdefault("wireless", {})
        w["count"] = len(out)

    def _station_list(self) -> list[dict[str, Any]]:
        if self.stations is not None:
            return self.stations
        w = self.status_doc.get("wireless", {})
        if not w.get("count", 1):
            return []
        ccq = w.get("ccq")
        mirrored = Station(
            mac="00:27:22:00:00:01",
            signal_dbm=w.get("signal"),
            ccq_pct=None if not isinstance(ccq, int | float) else ccq / 10,
            tx_mbps=_to_float(w.get("txrate")),
            rx_mbps=_to_float(w.get("rxrate")),
            noise_dbm=w.get("noisef"),
        )
        return [station_entry(mirrored)]

    # -- failure switches ------------------------------------------------------------------

    def set_password(self, password: str) -> None:
        """Change the radio's password (sessions already open stay open, as on airOS)."""
        self._password = password

    def expire_sessions(self) -> None:
        """Forget every session: the next request is sent to the login page."""
        self._sessions.clear()

    async def set_down(self, down: bool) -> None:
        """Down: refuse connections and cut the kept-alive ones; up: listen on the same port."""
        if down == self.down:
            return
        self.down = down
        if down:
            if self._site is not None:
                await self._site.stop()
                self._site = None
        else:
            await self._listen()

    # -- lifecycle -------------------------------------------------------------------------

    async def start(self) -> str:
        app = web.Application(middlewares=[self._middleware])
        app.router.add_get("/", self._root)
        app.router.add_get("/index.cgi", self._root)
        app.router.add_get("/login.cgi", self._login_page)
        app.router.add_post("/login.cgi", self._login_v6)
        app.router.add_get("/logout.cgi", self._logout)
        app.router.add_get("/status.cgi", self._status)
        app.router.add_get("/sta.cgi", self._sta)
        app.router.add_post("/api/auth", self._login_v8)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await self._runner.setup()
        await self._listen()
        return self.base_url or ""

    async def _listen(self) -> None:
        if self._runner is None:
            raise RuntimeError("FakeAirOs: start() first")
        self._site = web.TCPSite(
            self._runner, self.host, self.port, reuse_address=True, ssl_context=self.ssl_context
        )
        await self._site.start()
        if self.port == 0:
            self.port = int(self._runner.addresses[0][1])
        scheme = "https" if self.ssl_context is not None else "http"
        self.base_url = f"{scheme}://{self.host}:{self.port}"

    async def stop(self) -> None:
        if self._runner is not None:
            await self._runner.cleanup()
        self._runner = None
        self._site = None

    async def __aenter__(self) -> FakeAirOs:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # -- HTTP ------------------------------------------------------------------------------

    @web.middleware
    async def _middleware(self, request: web.Request, handler: _Handler) -> web.StreamResponse:
        if self.down:
            # A kept-alive connection opened before set_down(True): cut it like a dead radio.
            if request.transport is not None:
                request.transport.close()
            raise web.HTTPServiceUnavailable()
        self.counters["requests"] += 1
        if self.slow_s > 0:
            await self._clock.sleep(self.slow_s)
        return await handler(request)

    def _session(self, request: web.Request) -> tuple[str | None, _Session | None]:
        for name, value in request.cookies.items():
            if name.startswith("AIROS") and value in self._sessions:
                return value, self._sessions[value]
        return None, None

    def _new_session(self, response: web.StreamResponse) -> str:
        token = secrets.token_hex(16)
        self._sessions[token] = _Session()
        response.set_cookie(self._cookie_name, token, path="/")
        return token

    def _authorised(self, request: web.Request) -> bool:
        _, session = self._session(request)
        if session is None or not session.authed:
            return False
        return self.version == 6 or request.headers.get("X-CSRF-ID") == session.csrf_id

    def _not_logged_in(self, request: web.Request) -> web.StreamResponse:
        self.counters["redirects"] += 1
        if self.version == 8:
            return web.json_response({"error": "unauthorized"}, status=401)  # UNVERIFIED body
        response = _redirect(f"/login.cgi?uri={request.path}")
        if self._session(request)[1] is None:
            self._new_session(response)
        return response

    async def _root(self, request: web.Request) -> web.StreamResponse:
        if self._authorised(request):
            return web.Response(text="<html><body>airOS</body></html>", content_type="text/html")
        response = _redirect("/login.cgi?uri=/index.cgi")
        if self._session(request)[1] is None:
            self._new_session(response)
        return response

    async def _login_page(self, request: web.Request, error: str = "") -> web.StreamResponse:
        uri = request.query.get("uri", "/index.cgi")
        page = LOGIN_PAGE.format(uri=html.escape(uri), error=error)
        response = web.Response(text=page, content_type="text/html")
        if self._session(request)[1] is None:
            self._new_session(response)
        return response

    async def _login_v6(self, request: web.Request) -> web.StreamResponse:
        self.login_content_types.append(request.content_type)
        form = await request.post()
        _, session = self._session(request)
        username, password = form.get("username"), form.get("password")
        if session is None or username != self.username or password != self._password:
            self.counters["failed_logins"] += 1
            # The firmware answers a failed login with its login page again (docs/PROTOCOLS.md 4.1).
            return await self._login_page(
                request, error='<p class="error">Invalid credentials.</p>'
            )
        session.authed = True
        self.counters["logins"] += 1
        uri = form.get("uri")
        target = uri if isinstance(uri, str) and uri.startswith("/") else "/index.cgi"
        return _redirect(target)

    async def _login_v8(self, request: web.Request) -> web.StreamResponse:
        if self.version == 6:
            status = self.v6_api_auth_status
            if status in (301, 302, 303, 307):
                return _redirect("/login.cgi?uri=/api/auth")
            return web.Response(
                status=status, text=f"<html><body>{status}</body></html>", content_type="text/html"
            )
        try:
            body = await request.json()
        except ValueError:
            body = None
        if (
            not isinstance(body, dict)
            or body.get("username") != self.username
            or body.get("password") != self._password
        ):
            self.counters["failed_logins"] += 1
            return web.json_response({"error": "Invalid credentials"}, status=401)  # UNVERIFIED
        response = web.json_response({"ok": True, "fwversion": "v8.7.18"})
        token = self._new_session(response)
        session = self._sessions[token]
        session.authed = True
        session.csrf_id = secrets.token_hex(16)
        response.headers["X-CSRF-ID"] = session.csrf_id
        self.counters["logins"] += 1
        return response

    async def _logout(self, request: web.Request) -> web.StreamResponse:
        token, _ = self._session(request)
        if token is not None:
            self._sessions.pop(token, None)
            self.counters["logouts"] += 1
        return _redirect("/login.cgi")

    def _json(self, doc: object) -> web.Response:
        text = json.dumps(doc, indent=1)
        if self.malformed:
            text = text[: len(text) // 2]  # cut mid-document, as a dying connection would
        return web.Response(text=text, content_type="application/json")

    async def _status(self, request: web.Request) -> web.StreamResponse:
        if not self._authorised(request):
            return self._not_logged_in(request)
        self.counters["status"] += 1
        return self._json(self.status_doc)

    async def _sta(self, request: web.Request) -> web.StreamResponse:
        if not self._authorised(request):
            return self._not_logged_in(request)
        self.counters["sta"] += 1
        return self._json(self._station_list())


def _redirect(location: str) -> web.Response:
    return web.Response(status=302, headers={"Location": location})


def _to_float(value: object) -> float | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, int | float):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value.split()[0])
        except (ValueError, IndexError):
            return None
    return None
