"""The fleet page's web app: GET / (the page), GET /fleet.json, POST /api/hold-all.

Handlers answer from the pollers' memory only, so the page is as fast with a dead
relay as with none. Hold-all sends `hold` to every relay at once, each with its own
token and its own timeout, and reports each answer; it needs no token on this page:
it is the stop button, and a stop that asks for a password fails when it matters.
So the page binds to loopback by default. A browser cannot send its JSON body from
another site without a CORS preflight this app never grants, so a foreign page
cannot press it either.
"""

from __future__ import annotations

import asyncio
import json
import time
from importlib import resources
from pathlib import Path
from typing import Any

import aiohttp
import structlog
from aiohttp import web

from drivers.transport.clock import REAL_CLOCK, Clock
from relayd.api.hostcheck import normalise_names, request_problem
from relayd.fleet.chain import fleet_document
from relayd.fleet.config import FleetSettings, Relay
from relayd.fleet.poller import Fleet, short_error
from relayd.runtime.ratelimit import LogRateLimit

log = structlog.get_logger(__name__)

STATIC_DIR = Path(str(resources.files("relayd.fleet") / "static"))
HOLD_TIMEOUT_S = 2.0
FLEET: web.AppKey[Fleet] = web.AppKey("relayd_fleet", Fleet)
CSP = (
    "default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; "
    "connect-src 'self'"
)


def _json(value: Any, status: int = 200) -> web.Response:
    return web.Response(
        text=json.dumps(value, allow_nan=False, separators=(",", ":")),
        status=status,
        content_type="application/json",
        headers={"Cache-Control": "no-store"},
    )


async def handle_index(request: web.Request) -> web.Response:
    return web.Response(
        body=(STATIC_DIR / "index.html").read_bytes(),
        content_type="text/html",
        charset="utf-8",
        headers={"Content-Security-Policy": CSP, "Cache-Control": "no-cache"},
    )


async def handle_fleet(request: web.Request) -> web.Response:
    fleet = request.app[FLEET]
    return _json(fleet_document(fleet.views(), fleet.clock.now(), fleet.stale_after_s))


async def hold_one(
    session: aiohttp.ClientSession, relay: Relay, timeout_s: float
) -> dict[str, Any]:
    """POST {"mode": "hold"} to one relay; the result says plainly what happened."""
    result: dict[str, Any] = {"name": relay.name, "url": relay.url, "ok": False, "status": None}
    # A stop needs no token (docs/DEPLOY.md 6.1): it is sent to every relay, with the token
    # when one is configured.
    headers = {} if relay.token is None else {"Authorization": f"Bearer {relay.token}"}
    try:
        async with (
            asyncio.timeout(timeout_s),
            session.post(
                relay.url + "/api/mode",
                json={"mode": "hold"},
                headers=headers,
            ) as resp,
        ):
            text = await resp.text()
            result["status"] = resp.status
    except TimeoutError:
        return {**result, "message": f"no answer within {timeout_s:g} s: hold NOT confirmed"}
    except (aiohttp.ClientError, OSError) as exc:
        return {**result, "message": f"unreachable: hold NOT sent ({short_error(exc)})"}
    try:
        body = json.loads(text)
    except ValueError:
        body = {}
    if resp.status == 200:
        return {**result, "ok": True, "message": "hold accepted"}
    error = body.get("error") if isinstance(body, dict) else None
    return {**result, "message": f"refused: HTTP {resp.status} {error or ''}".rstrip()}


async def handle_hold_all(request: web.Request) -> web.Response:
    if request.content_type != "application/json":
        return _json({"error": "send Content-Type: application/json"}, 415)
    fleet = request.app[FLEET]
    if fleet.session is None:  # only between shutdown and the last request
        return _json({"error": "the fleet view is shutting down"}, 503)
    results = await asyncio.gather(
        *(hold_one(fleet.session, r, HOLD_TIMEOUT_S) for r in fleet.relays)
    )
    log.info(
        "fleet_hold_all", peer=request.remote, results={r["name"]: r["message"] for r in results}
    )
    return _json({"ok": all(r["ok"] for r in results), "results": list(results)})


def _host_middleware(allowed: frozenset[str]) -> Any:
    """Refuse a foreign Host (421) or Origin (403) on every route, as the relay's API does:
    a page the operator visits could otherwise rebind its name to this server and press
    hold-all. Refusals are logged at a bounded rate."""
    limit = LogRateLimit(60.0)

    @web.middleware
    async def check(request: web.Request, handler: Any) -> web.StreamResponse:
        problem = request_problem(
            request.headers.get("Host"), request.headers.get("Origin"), allowed
        )
        if problem is not None:
            count = limit.hit(f"host:{request.remote}", time.monotonic())
            if count is not None:
                log.warning("fleet_host_refused", peer=request.remote, reason=problem, count=count)
            status = 403 if problem.startswith("Origin") else 421
            return web.json_response({"error": problem}, status=status)
        resp: web.StreamResponse = await handler(request)
        return resp

    return check


def make_fleet_app(settings: FleetSettings, clock: Clock = REAL_CLOCK) -> web.Application:
    fleet = Fleet(
        settings.relays,
        poll_s=settings.poll_s,
        timeout_s=settings.timeout_s,
        stale_after_s=settings.stale_after_s,
        clock=clock,
    )
    app = web.Application(
        client_max_size=16 * 1024,
        middlewares=[_host_middleware(normalise_names(settings.allowed_hosts))],
    )
    app[FLEET] = fleet

    async def lifecycle(app: web.Application) -> Any:
        await fleet.start()
        yield
        await fleet.stop()

    app.cleanup_ctx.append(lifecycle)
    app.router.add_get("/", handle_index)
    app.router.add_get("/fleet.json", handle_fleet)
    app.router.add_post("/api/hold-all", handle_hold_all)
    app.router.add_static("/static/", STATIC_DIR, append_version=False)
    return app
