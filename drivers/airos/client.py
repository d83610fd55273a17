"""A small aiohttp client for Ubiquiti airOS radios: log in, read status.cgi / sta.cgi.

Login flows (docs/PROTOCOLS.md 4.1):

* airOS 5/6: `GET /` hands out an `AIROS_*` session cookie; `POST /login.cgi` (multipart
  form: username, password, uri) answers 302 to `uri` on success and the login page again
  on failure; the cookie then authorises `/status.cgi` and `/sta.cgi`.
* airOS 8: `POST /api/auth` (JSON) answers 200 with an `X-CSRF-ID` header and an `AIROS_*`
  cookie, both sent on every later request; 401/403 means wrong credentials.

With `firmware="auto"` the client tries `/api/auth` first and falls back to the v6 form when
the radio does not have it (404), like python-airos does.

Errors are translated into the small `AirOsError` family so the poller can decide per class:
re-login (`AirOsSessionExpired`), back off (`AirOsConnectionError`, `AirOsTimeoutError`),
count (`AirOsDataError`) or stop hammering (`AirOsAuthError`). The password is held in a
pydantic `SecretStr` and never appears in a message, a log line or a repr.
"""

from __future__ import annotations

import asyncio
import ssl
import warnings
from dataclasses import dataclass
from typing import Any, Literal

import aiohttp
import structlog
from pydantic import SecretStr
from yarl import URL

from drivers.airos.model import (
    AirOsDataError,
    AirOsError,
    LinkQuality,
    Station,
    decode_json,
    parse_stations,
    parse_status,
)
from drivers.transport.bounded import BodyTooLarge, read_bounded
from drivers.transport.clock import REAL_CLOCK, Clock

log = structlog.get_logger(__name__)

#: ssl.OP_LEGACY_SERVER_CONNECT (OpenSSL's SSL_OP_LEGACY_SERVER_CONNECT, 0x4); the ssl
#: module names it only from Python 3.12 on.
_OP_LEGACY_SERVER_CONNECT = 0x4

Firmware = Literal["auto", 6, 8]

#: Answers larger than this are not status documents (the real ones are ~3 KiB).
MAX_BODY_BYTES = 1 << 20
#: Wall seconds a closing client waits for its logout (the daemon's whole shutdown has 0.5 s).
LOGOUT_BUDGET_S = 0.1


class AirOsAuthError(AirOsError):
    """The radio refused the username/password: retrying soon will not help."""


class AirOsSessionExpired(AirOsError):
    """The session is gone (redirect to the login page, 401/403, an HTML answer)."""


class AirOsConnectionError(AirOsError):
    """No usable HTTP answer: refused, reset, TLS failure, 5xx."""


class AirOsTimeoutError(AirOsConnectionError):
    """No answer within the per-request timeout."""


class AirOsNotFound(AirOsDataError):
    """The radio has no such page (HTTP 404)."""


def legacy_tls_context() -> ssl.SSLContext:
    """A client context that can talk to airOS 6's lighttpd (TLS 1.0, legacy ciphers).

    OpenSSL 3 at the default SECLEVEL rejects those servers with a handshake failure
    (home-assistant/core #169302); the radios use self-signed certificates, so there is
    nothing to verify against either.
    """
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    try:
        with warnings.catch_warnings():  # TLS 1.0 is deprecated: that is the point here
            warnings.simplefilter("ignore", DeprecationWarning)
            ctx.minimum_version = ssl.TLSVersion.TLSv1
    except (ValueError, ssl.SSLError):  # a build without TLS 1.0 at all: keep its minimum
        log.warning("airos_tls10_unavailable")
    try:
        ctx.set_ciphers("DEFAULT:@SECLEVEL=0")
    except ssl.SSLError:  # pre-1.1 OpenSSL/LibreSSL have no security levels
        ctx.set_ciphers("DEFAULT")
    # Old lighttpd does not do RFC 5746 secure renegotiation; OpenSSL 3 refuses it otherwise.
    ctx.options |= _OP_LEGACY_SERVER_CONNECT
    return ctx


def _unverified_tls_context() -> ssl.SSLContext:
    """Modern TLS, but the radios' certificates are self-signed: no verification."""
    ctx = ssl.create_default_context()
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    return ctx


@dataclass(frozen=True, slots=True)
class _Answer:
    status: int
    content_type: str
    location: str
    csrf_id: str | None
    body: bytes

    def looks_like_html(self) -> bool:
        return "html" in self.content_type or self.body.lstrip()[:1] == b"<"


class AirOsClient:
    """One radio. Reuses one `aiohttp.ClientSession` (its own, or the one injected)."""

    def __init__(
        self,
        url: str,
        username: str,
        password: str | SecretStr,
        *,
        firmware: Firmware = "auto",
        legacy_tls: bool = False,
        timeout_s: float = 2.0,
        clock: Clock = REAL_CLOCK,
        session: aiohttp.ClientSession | None = None,
    ) -> None:
        base = URL(url)
        if base.scheme not in ("http", "https") or not base.host:
            raise ValueError(f"airOS url must be http://host or https://host, got {url!r}")
        if firmware not in ("auto", 6, 8):
            raise ValueError(f"firmware must be 'auto', 6 or 8, got {firmware!r}")
        if not timeout_s > 0:
            raise ValueError(f"timeout_s must be > 0, got {timeout_s!r}")
        self.base_url = URL.build(scheme=base.scheme, host=base.host, port=base.explicit_port)
        self.username = username
        self._password = password if isinstance(password, SecretStr) else SecretStr(password)
        self.firmware_setting: Firmware = firmware
        self.firmware: int | None = None if firmware == "auto" else firmware
        self.legacy_tls = legacy_tls
        self.timeout_s = timeout_s
        self._clock = clock
        self._session = session
        self._own_session = session is None
        self._ssl: ssl.SSLContext | None = None
        if base.scheme == "https":
            self._ssl = legacy_tls_context() if legacy_tls else _unverified_tls_context()
        self._cookie: tuple[str, str] | None = None
        self._csrf_id: str | None = None
        self.logged_in = False
        self._has_sta_cgi = True

    def __repr__(self) -> str:
        return (
            f"AirOsClient(url={str(self.base_url)!r}, username={self.username!r}, "
            f"firmware={self.firmware!r}, legacy_tls={self.legacy_tls!r}, logged_in={self.logged_in!r})"
        )

    @property
    def ssl_context(self) -> ssl.SSLContext | None:
        return self._ssl

    # -- transport -------------------------------------------------------------------------

    def _get_session(self) -> aiohttp.ClientSession:
        if self._session is None or (self._own_session and self._session.closed):
            # Cookies are handled by hand (radios are addressed by IP, which the default jar
            # refuses to store cookies for), so the session's own jar stays empty.
            self._session = aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar())
            self._own_session = True
        return self._session

    def _auth_headers(self) -> dict[str, str]:
        headers: dict[str, str] = {}
        if self._cookie is not None:
            headers["Cookie"] = f"{self._cookie[0]}={self._cookie[1]}"
        if self._csrf_id is not None:
            headers["X-CSRF-ID"] = self._csrf_id
        return headers

    async def _request(
        self,
        method: str,
        path: str,
        *,
        data: Any = None,
        json_body: Any = None,
        headers: dict[str, str] | None = None,
    ) -> _Answer:
        url = self.base_url.with_path(path)
        all_headers = self._auth_headers()
        all_headers.update(headers or {})
        timeout = aiohttp.ClientTimeout(total=self._clock.to_real(self.timeout_s))
        try:
            async with self._get_session().request(
                method,
                url,
                data=data,
                json=json_body,
                headers=all_headers,
                allow_redirects=False,
                timeout=timeout,
                ssl=self._ssl if self._ssl is not None else True,
            ) as resp:
                try:  # in pieces: a chunked answer carries no Content-Length
                    body = await read_bounded(resp, MAX_BODY_BYTES)
                except BodyTooLarge as exc:
                    raise AirOsDataError(f"{method} {path}: {exc}") from None
                for name, morsel in resp.cookies.items():
                    if name.upper().startswith("AIROS"):
                        self._cookie = (name, morsel.value)
                return _Answer(
                    status=resp.status,
                    content_type=resp.headers.get("Content-Type", "").lower(),
                    location=resp.headers.get("Location", ""),
                    csrf_id=resp.headers.get("X-CSRF-ID"),
                    body=body,
                )
        except TimeoutError:
            raise AirOsTimeoutError(
                f"{method} {path}: no answer within {self.timeout_s:g} s"
            ) from None
        except aiohttp.ClientError as exc:
            # aiohttp's messages name host:port and the OS error, never the request body.
            raise AirOsConnectionError(f"{method} {path}: {type(exc).__name__}: {exc}") from None

    # -- login ----------------------------------------------------------------------------

    async def login(self) -> None:
        """Open a session; raises AirOsAuthError on wrong credentials."""
        self.logged_in = False
        self._cookie = None
        self._csrf_id = None
        if self.firmware_setting in ("auto", 8) and await self._login_v8():
            self.firmware = 8
        else:
            await self._login_v6()
            self.firmware = 6
        self.logged_in = True
        log.info("airos_logged_in", url=str(self.base_url), firmware=self.firmware)

    async def _login_v8(self) -> bool:
        """True when logged in; False when the radio has no /api/auth (airOS 5/6)."""
        answer = await self._request(
            "POST",
            "/api/auth",
            json_body={"username": self.username, "password": self._password.get_secret_value()},
        )
        refused = answer.status in (401, 403)
        # An airOS 8 refusal is a JSON answer of its API; in "auto" mode a bare 401/403 page
        # may be an airOS 5/6 lighttpd guarding a path it does not have (UNVERIFIED), so
        # only the JSON kind is taken as wrong credentials there.
        if refused and (self.firmware_setting == 8 or "json" in answer.content_type):
            raise AirOsAuthError(
                f"airOS 8 login refused for user {self.username!r} (HTTP {answer.status})"
            )
        if answer.status == 200 and answer.csrf_id:
            self._csrf_id = answer.csrf_id
            return True
        if self.firmware_setting == 8:
            raise AirOsConnectionError(f"POST /api/auth: unexpected HTTP {answer.status}")
        self._cookie = None  # whatever a v6 radio set while saying 404 is not a login
        return False

    async def _login_v6(self) -> None:
        await self._request("GET", "/")
        if self._cookie is None:  # airOS 5 hands the cookie out on the login page itself
            await self._request("GET", "/login.cgi")
        if self._cookie is None:
            raise AirOsDataError("airOS login page set no AIROS_* session cookie")
        form = aiohttp.MultipartWriter("form-data")
        for name, value in (
            ("uri", "/status.cgi"),
            ("username", self.username),
            ("password", self._password.get_secret_value()),
        ):
            part = form.append(value)
            part.set_content_disposition("form-data", name=name)
        origin = str(self.base_url)
        answer = await self._request(
            "POST",
            "/login.cgi",
            data=form,
            headers={"Origin": origin, "Referer": origin + "/login.cgi"},
        )
        if answer.status in (301, 302, 303, 307) and "login.cgi" not in answer.location:
            return
        if answer.status == 200 or (
            answer.status in (301, 302, 303, 307) and "login.cgi" in answer.location
        ):
            # The firmware shows its login page again: the credentials were wrong.
            raise AirOsAuthError(f"airOS login refused for user {self.username!r}")
        raise AirOsConnectionError(f"POST /login.cgi: unexpected HTTP {answer.status}")

    async def logout(self) -> None:
        """Free the radio's session slot (airOS 5/6 `/logout.cgi`); best effort."""
        if self.logged_in and self.firmware == 6:
            try:
                await self._request("GET", "/logout.cgi")
            except AirOsError as exc:
                log.debug("airos_logout_failed", url=str(self.base_url), error=str(exc))
        self.logged_in = False
        self._cookie = None
        self._csrf_id = None

    async def close(self, logout_budget_s: float = LOGOUT_BUDGET_S) -> None:
        """Log out (best effort, at most `logout_budget_s` wall seconds) and close our session.

        The logout is a courtesy to the radio's session table; a slow or dead radio must
        not hold up the daemon's shutdown, nor leave the HTTP session open.
        """
        try:
            async with asyncio.timeout(logout_budget_s):
                await self.logout()
        except TimeoutError:
            log.debug("airos_logout_skipped", url=str(self.base_url), budget_s=logout_budget_s)
            self.logged_in = False
            self._cookie = None
            self._csrf_id = None
        finally:
            if self._own_session and self._session is not None:
                await self._session.close()
            self._session = None

    # -- data ------------------------------------------------------------------------------

    async def _get_json(self, path: str) -> Any:
        answer = await self._request("GET", path)
        if answer.status in (301, 302, 303, 307, 308):
            self.logged_in = False
            raise AirOsSessionExpired(f"GET {path}: redirected to {answer.location or '?'}")
        if answer.status in (401, 403):
            self.logged_in = False
            raise AirOsSessionExpired(f"GET {path}: HTTP {answer.status}")
        if answer.status == 404:
            raise AirOsNotFound(f"GET {path}: HTTP 404")
        if answer.status != 200:
            raise AirOsConnectionError(f"GET {path}: HTTP {answer.status}")
        try:
            return decode_json(answer.body, path)
        except AirOsDataError:
            if answer.looks_like_html():
                # A login page served with 200 (some firmware does not redirect).
                self.logged_in = False
                raise AirOsSessionExpired(f"GET {path}: HTML instead of JSON") from None
            raise

    async def status(self) -> Any:
        """The raw decoded status.cgi document."""
        return await self._get_json("/status.cgi")

    async def stations(self) -> tuple[Station, ...]:
        """The AP's station list (`/sta.cgi`, airOS 5/6)."""
        return parse_stations(await self._get_json("/sta.cgi"))

    async def fetch(self, t: float | None = None) -> LinkQuality:
        """Log in if needed, read status.cgi (and sta.cgi on an AP), return the link quality."""
        if not self.logged_in:
            await self.login()
        now = self._clock.now() if t is None else t
        doc = await self.status()
        quality = parse_status(doc, t=now)
        wireless = doc.get("wireless") if isinstance(doc, dict) else None
        embedded = isinstance(wireless, dict) and isinstance(wireless.get("sta"), list)
        if quality.mode == "ap" and not embedded and self._has_sta_cgi:
            try:
                stations = await self.stations()
            except AirOsNotFound:
                self._has_sta_cgi = False  # firmware without sta.cgi: don't ask every second
                log.warning("airos_no_sta_cgi", url=str(self.base_url))
            else:
                quality = parse_status(doc, t=now, stations=stations)
        return quality
