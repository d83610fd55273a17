"""The HTTP API, live page and metrics endpoint of one relayd (`/openapi.json` describes it).

The app only reads `RelayState` and calls `Controls`; every handler answers from
memory without waiting on a device, so /status stays fast while the control loop runs.
Control endpoints need the configured bearer token: none configured means disabled
(403), never open. The one exception is a stop: `POST /api/mode {"mode": "hold"}` needs
no token, because stopping is always safe and anyone who can see the robot may stop it
(the e-stop rule; docs/DEPLOY.md). Failed authentication backs a client off (429), and
event streams are capped per client and in total, below the connection cap, so the
status and control routes always have room. No secret is ever put in a response or a
log line.
"""

from __future__ import annotations

import asyncio
import hmac
import json
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

import structlog
from aiohttp import web
from prometheus_client.aiohttp import make_aiohttp_handler
from pydantic import BaseModel, ValidationError

from drivers.transport.clock import Clock
from relayd.api.history import History
from relayd.api.history import install as install_history
from relayd.api.hostcheck import normalise_names, request_problem
from relayd.api.models import DriveRequest, ModeRequest
from relayd.api.openapi import build_openapi
from relayd.api.server import start_api
from relayd.core.vocab import Mode
from relayd.runtime.metrics import Metrics
from relayd.runtime.ratelimit import LogRateLimit
from relayd.runtime.state import Controls, ModeError, RelayState

log = structlog.get_logger(__name__)
_M = TypeVar("_M", bound=BaseModel)

#: The P3-AT's absolute wheel speed limit (ARIA p3at.p MaxVelocity); the controller
#: clamps further to v_max, this only rejects nonsense at the door.
DEFAULT_MAX_DRIVE_MM_S = 1200.0
#: Control bodies are a few dozen bytes; anything large is a mistake or an attack.
MAX_BODY_BYTES = 16 * 1024
#: Event streams in all and per client; the guard admits MAX_CONNECTIONS (100).
MAX_STREAMS = 32
MAX_STREAMS_PER_CLIENT = 4
#: After a failed authentication a client is refused for AUTH_BACKOFF_S * 2^(n-1) s, up to
#: AUTH_BACKOFF_MAX_S: a guess costs a dictionary look-up, and 3,970 guesses a second
#: become a few a minute.
AUTH_BACKOFF_S = 0.5
AUTH_BACKOFF_MAX_S = 30.0
#: Failures in a row a client may make before the backoff starts (a mistyped token).
AUTH_FREE_FAILURES = 10
#: Clients whose failures are remembered; beyond it the oldest is forgotten.
AUTH_BACKOFF_CLIENTS = 1024

#: Refused-token warnings: at most one per client and this many seconds, with a count.
AUTH_LOG_EVERY_S = 60.0
STATIC_DIR = Path(str(resources.files("relayd.api") / "static"))


@dataclass(slots=True)
class ApiContext:
    """What the handlers share; stored in the app under `CONTEXT`."""

    state: RelayState
    controls: Controls
    clock: Clock
    token: str | None
    metrics: Metrics
    healthz_max_age_s: float
    max_drive_mm_s: float
    sse_heartbeat_s: float
    sse_min_interval_s: float
    openapi_body: bytes
    index_body: bytes
    sse_tasks: set[asyncio.Task[Any]] = field(default_factory=set)
    auth_log_limit: LogRateLimit = field(default_factory=lambda: LogRateLimit(AUTH_LOG_EVERY_S))
    #: Unauthenticated stops are logged at most once per client and this period.
    stop_log_limit: LogRateLimit = field(default_factory=lambda: LogRateLimit(AUTH_LOG_EVERY_S))
    #: Event streams: at most this many in all and per client (below the guard's connection
    #: cap, so /healthz, /status and the control routes always find room).
    max_streams: int = MAX_STREAMS
    max_streams_per_client: int = MAX_STREAMS_PER_CLIENT
    streams_by_client: dict[str, int] = field(default_factory=dict)
    #: Failed authentications per client: (failures in a row, refused until clock time).
    auth_backoff: dict[str, tuple[int, float]] = field(default_factory=dict)
    auth_free_failures: int = AUTH_FREE_FAILURES
    #: The last /status body and what it was rendered for: (state revision, clock time).
    status_cache: tuple[int, float, str] | None = None


CONTEXT: web.AppKey[ApiContext] = web.AppKey("relayd_api", ApiContext)


def _scrub(value: Any) -> Any:
    """Non-finite floats become null so the document stays valid JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _scrub(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_scrub(v) for v in value]
    return value


def dumps(value: Any) -> str:
    """Compact JSON; a NaN that slipped into the state turns into null instead of invalid JSON."""
    try:
        return json.dumps(value, allow_nan=False, separators=(",", ":"))
    except ValueError:
        return json.dumps(_scrub(value), allow_nan=False, separators=(",", ":"))


def _json(value: Any, status: int = 200, headers: dict[str, str] | None = None) -> web.Response:
    return web.Response(
        text=dumps(value), status=status, content_type="application/json", headers=headers
    )


def _error(status: int, message: str, field_name: str | None = None, **extra: Any) -> web.Response:
    body: dict[str, Any] = {"error": message, "field": field_name, **extra}
    headers = {"WWW-Authenticate": 'Bearer realm="relayd"'} if status == 401 else None
    return _json(body, status, headers)


class _BadRequest(Exception):
    def __init__(self, message: str, field_name: str | None) -> None:
        super().__init__(message)
        self.field_name = field_name


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not a JSON number")


async def _parse_body(request: web.Request, model: type[_M]) -> _M:
    raw = await request.read()
    try:
        data = json.loads(raw, parse_constant=_reject_constant)
    except (ValueError, RecursionError) as exc:
        raise _BadRequest(f"body is not valid JSON: {exc}", None) from exc
    if not isinstance(data, dict):
        raise _BadRequest("body must be a JSON object", None)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        first = exc.errors(include_url=False, include_input=False)[0]
        loc = ".".join(str(part) for part in first["loc"]) or None
        raise _BadRequest(first["msg"], loc) from exc


def _auth_warning(ctx: ApiContext, event: str, request: web.Request) -> None:
    """A refused token is worth a warning, but not one per request: anyone on the bridge
    can send them as fast as they like. First one at once, then one a minute with a count."""
    count = ctx.auth_log_limit.hit(f"{event}:{request.remote}", ctx.clock.now())
    if count is not None:
        log.warning(
            event,
            path=request.path,
            peer=request.remote,
            count=count,
            every_s=ctx.auth_log_limit.every_s,
        )


def _authorize(ctx: ApiContext, request: web.Request) -> web.Response | None:
    """None when the bearer token matches; otherwise the 401/403/429 to send."""
    if not ctx.token:
        return _error(403, "control endpoints are disabled: no API token is configured")
    client = request.remote or "?"
    now = ctx.clock.now()
    failures, until_t = ctx.auth_backoff.get(client, (0, 0.0))
    if now < until_t:
        wait_s = math.ceil(until_t - now)
        message = f"too many failed authentications: retry in {wait_s} s"
        return web.json_response(
            {"error": message}, status=429, headers={"Retry-After": str(wait_s)}, dumps=dumps
        )
    scheme, _, presented = request.headers.get("Authorization", "").partition(" ")
    presented = presented.strip()
    if scheme.lower() != "bearer" or not presented:
        _auth_warning(ctx, "api_auth_missing", request)
        _auth_failed(ctx, client, failures, now)
        return _error(401, "missing bearer token")
    # Compare bytes: compare_digest refuses non-ASCII str, and a header may hold anything.
    if not hmac.compare_digest(
        presented.encode("utf-8", "backslashreplace"), ctx.token.encode("utf-8")
    ):
        _auth_warning(ctx, "api_auth_failed", request)
        _auth_failed(ctx, client, failures, now)
        return _error(401, "wrong bearer token")
    ctx.auth_backoff.pop(client, None)
    return None


def _auth_failed(ctx: ApiContext, client: str, failures: int, now: float) -> None:
    failures += 1
    over = failures - ctx.auth_free_failures
    until_t = (
        now + min(AUTH_BACKOFF_MAX_S, AUTH_BACKOFF_S * 2.0 ** min(over, 16)) if over > 0 else 0.0
    )
    ctx.auth_backoff.pop(client, None)  # re-inserted last: the dict's order is its age
    ctx.auth_backoff[client] = (failures, until_t)
    while len(ctx.auth_backoff) > AUTH_BACKOFF_CLIENTS:
        del ctx.auth_backoff[next(iter(ctx.auth_backoff))]


#: How long a rendered /status body is served again while the state has not changed (s).
#: Under a poll flood (a dashboard wall, a scraper gone wrong) the snapshot and its JSON,
#: about 60 us with every driver's health read, would otherwise be redone per request;
#: ages and uptime in the body are then at most this old. Any state change renders anew.
STATUS_REUSE_S = 0.05


async def handle_status(request: web.Request) -> web.Response:
    ctx = request.app[CONTEXT]
    now = ctx.clock.now()
    cached = ctx.status_cache
    if (
        cached is None
        or cached[0] != ctx.state.revision
        or not 0.0 <= now - cached[1] < STATUS_REUSE_S
    ):
        cached = (ctx.state.revision, now, dumps(ctx.state.snapshot(now)))
        ctx.status_cache = cached
    return web.Response(text=cached[2], content_type="application/json")


async def handle_path(request: web.Request) -> web.Response:
    """This relay's odometry pose and path, for a relay that follows it (read-only)."""
    source = request.app[CONTEXT].state.path_source
    doc = {"pose": None, "points": []} if source is None else source()
    return web.Response(text=dumps(doc), content_type="application/json")


async def handle_healthz(request: web.Request) -> web.Response:
    ctx = request.app[CONTEXT]
    st = ctx.state
    body: dict[str, Any] = {
        "mode": str(st.mode),
        "state": str(st.state),
        "max_age_s": ctx.healthz_max_age_s,
    }
    if st.loop_tick_t is None:
        return _json(
            {"ok": False, "reason": "control loop has not ticked yet", "loop_age_s": None, **body},
            503,
        )
    age_s = max(0.0, ctx.clock.now() - st.loop_tick_t)
    body["loop_age_s"] = round(age_s, 3)
    if age_s > ctx.healthz_max_age_s:
        return _json(
            {"ok": False, "reason": f"control loop stalled: last tick {age_s:.3f} s ago", **body},
            503,
        )
    return _json({"ok": True, "reason": "control loop alive", **body})


async def handle_openapi(request: web.Request) -> web.Response:
    return web.Response(body=request.app[CONTEXT].openapi_body, content_type="application/json")


async def handle_index(request: web.Request) -> web.Response:
    return web.Response(
        body=request.app[CONTEXT].index_body,
        content_type="text/html",
        charset="utf-8",
        headers={
            # Everything the page needs comes from this server: it must work offline.
            "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; "
            "style-src 'self'; script-src 'self'; connect-src 'self'",
            "Cache-Control": "no-cache",
        },
    )


async def handle_mode(request: web.Request) -> web.Response:
    ctx = request.app[CONTEXT]
    try:
        req = await _parse_body(request, ModeRequest)
    except _BadRequest as exc:
        # A malformed body costs the sender nothing more than its 400, token or not.
        denied = _authorize(ctx, request)
        return denied if denied is not None else _error(400, str(exc), exc.field_name)
    if req.mode is not Mode.HOLD:
        denied = _authorize(ctx, request)
        if denied is not None:
            return denied
    elif "Authorization" not in request.headers:
        # A stop needs no token; it is logged, at a rate no script can flood.
        count = ctx.stop_log_limit.hit(f"stop:{request.remote}", ctx.clock.now())
        if count:
            log.warning("api_stop_without_token", peer=request.remote, count=count)
    try:
        ctx.controls.set_mode(req.mode)
    except ModeError as exc:
        return _error(409, str(exc), "mode", mode=str(ctx.state.mode))
    log.info("api_mode_set", mode=str(req.mode), peer=request.remote)
    return _json({"ok": True, "mode": str(req.mode)})


async def handle_drive(request: web.Request) -> web.Response:
    ctx = request.app[CONTEXT]
    denied = _authorize(ctx, request)
    if denied is not None:
        return denied
    try:
        req = await _parse_body(request, DriveRequest)
    except _BadRequest as exc:
        return _error(400, str(exc), exc.field_name)
    for name, value in (("left_mm_s", req.left_mm_s), ("right_mm_s", req.right_mm_s)):
        if abs(value) > ctx.max_drive_mm_s:
            return _error(400, f"{name} must be within ±{ctx.max_drive_mm_s:g} mm/s", name)
    try:
        ctx.controls.manual_drive(req.left_mm_s, req.right_mm_s)
    except ModeError as exc:
        return _error(409, str(exc), None, mode=str(ctx.state.mode))
    log.debug("api_drive", left_mm_s=req.left_mm_s, right_mm_s=req.right_mm_s, peer=request.remote)
    return _json({"ok": True, "left_mm_s": req.left_mm_s, "right_mm_s": req.right_mm_s})


def _sse(event: str, data: str, event_id: int | None = None) -> bytes:
    head = f"id: {event_id}\n" if event_id is not None else ""
    return f"{head}event: {event}\ndata: {data}\n\n".encode()


async def handle_events(request: web.Request) -> web.StreamResponse:
    """Push the status document whenever `state.touch()` fires; heartbeat while idle."""
    ctx = request.app[CONTEXT]
    state, clock = ctx.state, ctx.clock
    resp = web.StreamResponse(
        headers={
            "Content-Type": "text/event-stream",
            "Cache-Control": "no-cache",
            # Tell reverse proxies not to buffer the stream.
            "X-Accel-Buffering": "no",
        }
    )
    client = request.remote or "?"
    mine = ctx.streams_by_client.get(client, 0)
    if len(ctx.sse_tasks) >= ctx.max_streams or mine >= ctx.max_streams_per_client:
        return web.json_response(
            {"error": "too many event streams: poll /status instead, or retry later"},
            status=503,
            headers={"Retry-After": "5"},
        )
    task = asyncio.current_task()
    if task is not None:
        ctx.sse_tasks.add(task)
    ctx.streams_by_client[client] = mine + 1
    try:
        await resp.prepare(request)
        # Clients reconnect after 2 s if the robot restarts.
        await resp.write(b"retry: 2000\n\n")
        sent_rev = state.revision
        await resp.write(_sse("status", dumps(state.snapshot(clock.now())), sent_rev))
        while True:
            changed = state.changed  # touch() replaces the event: take it before checking
            if state.revision == sent_rev:
                try:
                    async with clock.timeout(ctx.sse_heartbeat_s):
                        await changed.wait()
                except TimeoutError:
                    beat = {
                        "uptime_s": round(clock.now() - state.started_t, 3),
                        "revision": state.revision,
                    }
                    await resp.write(_sse("heartbeat", dumps(beat)))
                continue
            sent_rev = state.revision
            await resp.write(_sse("status", dumps(state.snapshot(clock.now())), sent_rev))
            # Coalesce bursts of touches (10 Hz SIPs plus scans) into a bounded event rate.
            await clock.sleep(ctx.sse_min_interval_s)
    except (ConnectionResetError, ConnectionError):
        log.debug("sse_client_gone", peer=request.remote)
    finally:
        if task is not None:
            ctx.sse_tasks.discard(task)
        left = ctx.streams_by_client.get(client, 1) - 1
        if left > 0:
            ctx.streams_by_client[client] = left
        else:
            ctx.streams_by_client.pop(client, None)
    return resp


async def _close_streams(app: web.Application) -> None:
    """Event streams never end by themselves: cancel them so shutdown does not wait."""
    for task in list(app[CONTEXT].sse_tasks):
        task.cancel()


def _host_middleware(allowed: frozenset[str]) -> Any:
    """Refuse a foreign Host (421) or Origin (403) on every route: DNS rebinding (hostcheck.py)."""

    @web.middleware
    async def check(request: web.Request, handler: Any) -> web.StreamResponse:
        host = request.headers.get("Host")
        problem = request_problem(host, request.headers.get("Origin"), allowed)
        if problem is not None:
            ctx = request.app[CONTEXT]
            count = ctx.auth_log_limit.hit(f"host:{request.remote}", ctx.clock.now())
            if count is not None:
                log.warning("api_host_refused", peer=request.remote, reason=problem, count=count)
            status = 403 if problem.startswith("Origin") else 421
            return _error(status, problem, "Origin" if status == 403 else "Host")
        resp: web.StreamResponse = await handler(request)
        return resp

    return check


@web.middleware
async def _headers_middleware(request: web.Request, handler: Any) -> web.StreamResponse:
    response: web.StreamResponse = await handler(request)
    response.headers.setdefault("X-Content-Type-Options", "nosniff")
    return response


def make_app(
    state: RelayState,
    controls: Controls,
    *,
    clock: Clock,
    token: str | None,
    metrics: Metrics | None = None,
    healthz_max_age_s: float = 1.0,
    max_drive_mm_s: float = DEFAULT_MAX_DRIVE_MM_S,
    sse_heartbeat_s: float = 1.0,
    sse_min_interval_s: float = 0.1,
    allowed_hosts: tuple[str, ...] = (),
) -> web.Application:
    """The relayd web application. `metrics` defaults to a fresh `Metrics(state, clock)`.

    The heartbeat is short because the live page treats 2 s without any event as stale
    data: a daemon that is alive but unchanged must say so well within that.
    `allowed_hosts` are the names (beyond IP addresses and localhost) the Host and
    Origin headers may carry.
    """
    if metrics is None:
        metrics = Metrics(state, clock)
    ctx = ApiContext(
        state=state,
        controls=controls,
        clock=clock,
        token=token or None,
        metrics=metrics,
        healthz_max_age_s=healthz_max_age_s,
        max_drive_mm_s=max_drive_mm_s,
        sse_heartbeat_s=sse_heartbeat_s,
        sse_min_interval_s=sse_min_interval_s,
        openapi_body=json.dumps(build_openapi(max_drive_mm_s), indent=1).encode(),
        index_body=(STATIC_DIR / "index.html").read_bytes(),
    )
    app = web.Application(
        client_max_size=MAX_BODY_BYTES,
        middlewares=[_host_middleware(normalise_names(allowed_hosts)), _headers_middleware],
    )
    app[CONTEXT] = ctx
    app.router.add_get("/", handle_index)
    app.router.add_get("/status", handle_status)
    app.router.add_get("/healthz", handle_healthz)
    app.router.add_get("/path", handle_path)
    app.router.add_get("/metrics", make_aiohttp_handler(metrics.registry))
    app.router.add_get("/openapi.json", handle_openapi)
    app.router.add_get("/events", handle_events)
    app.router.add_post("/api/mode", handle_mode)
    app.router.add_post("/api/drive", handle_drive)
    app.router.add_static("/static/", STATIC_DIR, append_version=False)
    install_history(app, History(state.snapshot, clock), _json)
    app.on_shutdown.append(_close_streams)
    return app


#: `start_api` lives in relayd/api/server.py (behind the guarded accept loop of
#: relayd/api/guard.py); importable from here too.
__all__ = ["make_app", "start_api"]
