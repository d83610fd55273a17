"""Host and Origin checks against DNS rebinding, shared by every HTTP server relayd runs.

A web page the operator visits can rebind its own name to a relay's address: the
browser then sends the page's requests to the relay, with the attacker's name in
`Host` (and in `Origin`, when there is one). Refusing names we were not told about
closes that. An IP literal can never be rebound (there is no name to re-resolve), so
any IP address passes, as does `localhost`; every other name must be listed in the
configuration (`[api] allowed_hosts`). Pure functions: the servers call them from a
middleware and answer 421/403 with the reason.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Iterable
from urllib.parse import urlsplit

#: Names that always resolve to this machine and that no page can take over.
LOOPBACK_NAMES = frozenset({"localhost", "localhost.localdomain", "ip6-localhost"})


def normalise_names(names: Iterable[str]) -> frozenset[str]:
    """Lower-cased names without a trailing dot, the form `host_allowed` compares."""
    return frozenset(n.strip().lower().rstrip(".") for n in names if n.strip())


def split_host(host_header: str) -> str | None:
    """The name or address of a `Host` value (port and IPv6 brackets removed); None if malformed."""
    value = host_header.strip()
    if not value:
        return None
    if value.startswith("["):
        end = value.find("]")
        if end < 0:
            return None
        rest = value[end + 1 :]
        if rest and not (rest.startswith(":") and rest[1:].isdigit()):
            return None
        return value[1:end].lower()
    name, sep, port = value.rpartition(":")
    if sep and port.isdigit() and ":" not in name:
        value = name
    elif sep and ":" not in name:
        return None  # "name:" or "name:abc"
    return value.lower().rstrip(".")


def host_allowed(name: str, allowed: frozenset[str]) -> bool:
    """True for an IP literal, a loopback name, or a name in `allowed` (normalised)."""
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return name in LOOPBACK_NAMES or name in allowed
    return True


def request_problem(host: str | None, origin: str | None, allowed: frozenset[str]) -> str | None:
    """Why a request with these `Host` and `Origin` headers is refused, or None if it is fine.

    A request without `Origin` (curl, Prometheus, a same-origin GET) is judged on its
    Host alone. With one, its host must be the Host's or a listed name; `Origin: null`
    (a sandboxed or file:// page) is refused.
    """
    if host is None:
        return "the request has no Host header"
    name = split_host(host)
    if name is None:
        return f"malformed Host header {host!r}"
    if not host_allowed(name, allowed):
        return f"Host {name!r} is not an allowed name (add it to [api] allowed_hosts)"
    if origin is None:
        return None
    parts = urlsplit(origin.strip())
    if parts.scheme not in ("http", "https") or not parts.hostname:
        return f"Origin {origin!r} is not an http(s) origin"
    origin_name = parts.hostname.lower().rstrip(".")
    # Same origin, or a name listed on purpose: an IP-literal page elsewhere is no
    # rebinding, but it is another site, and a stop needs no token.
    if origin_name != name and origin_name not in allowed:
        return (
            f"Origin {origin_name!r} is not this server nor an allowed name ([api] allowed_hosts)"
        )
    return None
