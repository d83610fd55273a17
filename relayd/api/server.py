"""Serving the API: the listening socket, TLS, and aiohttp behind the connection guard.

`start_api` binds the socket, builds aiohttp's runner and hands the socket to the
`GuardedServer` (relayd/api/guard.py: connection cap, idle deadline, descriptor
reserve), whose middleware marks requests in progress; the TLS context comes from
relayd.config.tls. `install_accept_error_limit` rate-limits asyncio's own accept-error reports, for any
other server in the process.
"""

from __future__ import annotations

import asyncio
import socket
import ssl
from typing import Any

import structlog
from aiohttp import web

from drivers.transport.loopreports import add_report_filter
from relayd.api.guard import LOG_EVERY_S, GuardedServer
from relayd.runtime.ratelimit import LogRateLimit

log = structlog.get_logger(__name__)

LISTEN_BACKLOG = 128
_ACCEPT_RESOURCE_MESSAGE = "socket.accept() out of system resource"


class ApiServer:
    """What `start_api` returns: stop it with `await cleanup()`."""

    def __init__(self, runner: web.AppRunner, guard: GuardedServer) -> None:
        self.runner = runner
        self.guard = guard

    async def cleanup(self) -> None:
        await self.guard.close()
        try:
            await self.runner.cleanup()
        finally:
            self.guard.abort_all()


class _AcceptErrorLimit:
    """A drivers.transport.loopreports filter: asyncio's accept-resource reports, rate-limited."""

    def __init__(self) -> None:
        self._limit = LogRateLimit(LOG_EVERY_S)

    def __call__(self, lp: asyncio.AbstractEventLoop, context: dict[str, Any]) -> bool:
        if context.get("message") != _ACCEPT_RESOURCE_MESSAGE:
            return False
        count = self._limit.hit("accept", lp.time())
        if count is not None:
            log.warning(
                "accept_failed",
                error=str(context.get("exception")),
                count=count,
                every_s=LOG_EVERY_S,
            )
        return True


def install_accept_error_limit(loop: asyncio.AbstractEventLoop) -> None:
    """Rate-limit asyncio's own 'accept() out of system resource' reports for this loop.

    relayd's API does not go through asyncio's accept loop, but any other server in the
    process would: under descriptor exhaustion asyncio reports every failed accept, tens
    of thousands of lines a minute. Other reports go to the previous handler unchanged.
    """
    add_report_filter(loop, "accept_limit", _AcceptErrorLimit())


def listen_socket(host: str, port: int) -> socket.socket:
    """A listening TCP socket on host:port (0 = ephemeral); OSError if it cannot bind."""
    infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    family = infos[0][0]
    return socket.create_server((host, port), family=family, backlog=LISTEN_BACKLOG)


async def start_api(
    app: web.Application,
    host: str,
    port: int,
    *,
    ssl_context: ssl.SSLContext | None = None,
    guard: GuardedServer | None = None,
) -> tuple[ApiServer, int]:
    """Serve `app` on host:port (0 = ephemeral), HTTPS with `ssl_context`; returns the server and port.

    Stop with `await server.cleanup()`. The access log is off: the live page and
    Prometheus poll constantly, and control requests are logged by their handlers.
    """
    guard = guard or GuardedServer()
    loop = asyncio.get_running_loop()
    install_accept_error_limit(loop)
    app.middlewares.insert(0, guard.middleware)
    # keepalive_timeout is aiohttp's own idle limit; the guard's sweep enforces the same
    # deadline on connections that never finished a request.
    runner = web.AppRunner(
        app, access_log=None, shutdown_timeout=2.0, keepalive_timeout=guard.idle_timeout_s
    )
    await runner.setup()
    try:
        sock = listen_socket(host, port)
    except BaseException:
        await runner.cleanup()
        raise
    if runner.server is None:  # AppRunner.setup() always makes one
        await runner.cleanup()
        sock.close()
        raise RuntimeError("aiohttp's runner has no server after setup()")
    guard.start(sock, runner.server, ssl_context)
    bound = int(sock.getsockname()[1])
    log.info(
        "api_listening",
        host=host,
        port=bound,
        tls=ssl_context is not None,
        max_connections=guard.max_connections,
        fd_limit=guard.fd_limit,
    )
    return ApiServer(runner, guard), bound
