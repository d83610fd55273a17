"""`[control] leader_url` and its keys: the leader relay's API, the start poses' prior, the
trail pursuit; each mistake named by its key; unset is today's behaviour (no feed)."""

from __future__ import annotations

import pytest

from relayd.config.load import parse_settings
from relayd.config.model import ConfigError
from relayd.config.params import trail_params
from relayd.core.trail.align import Frame

BASE = {"rear_link": "ignore", "pursuit": "trail"}


def _errors(control: dict[str, object]) -> list[str]:
    with pytest.raises(ConfigError) as ei:
        parse_settings({"control": control})
    return ei.value.errors


def test_unset_is_no_feed() -> None:
    s = parse_settings({"control": {"rear_link": "ignore"}})
    assert s.control.leader_url is None
    assert trail_params(s).feed.prior is None


def test_a_leader_url_with_its_origin_is_the_feed_and_its_prior() -> None:
    s = parse_settings(
        {"control": {**BASE, "leader_url": "http://10.0.0.31:8080/", "leader_origin": [1.5, 0, 0]}}
    )
    assert s.control.leader_url == "http://10.0.0.31:8080"
    feed = trail_params(s).feed
    assert feed.prior == Frame(1.5, 0.0, 0.0) and feed.stale_s == s.control.leader_stale_s


@pytest.mark.parametrize(
    ("url", "why"),
    [
        ("ftp://10.0.0.31", "http(s)://host:port"),
        ("10.0.0.31:8080", "http(s)://host:port"),
        ("http://10.0.0.31:80x", "bad port"),
        ("http://10.0.0.31:8080/path", "no path, query or fragment"),
        ("http://10.0.0.31:8080?x=1", "no path, query or fragment"),
    ],
)
def test_a_bad_url_is_named(url: str, why: str) -> None:
    errors = _errors({**BASE, "leader_url": url, "leader_origin": [1, 0, 0]})
    assert any(e.startswith("control.leader_url") and why in e for e in errors), errors


def test_the_feed_needs_its_origin_and_the_trail_pursuit() -> None:
    errors = _errors({**BASE, "leader_url": "http://10.0.0.31:8080"})
    assert any(e.startswith("control.leader_origin: is needed with leader_url") for e in errors)
    errors = _errors(
        {"rear_link": "ignore", "leader_url": "http://10.0.0.31:8080", "leader_origin": [1, 0, 0]}
    )
    assert any(e.startswith("control.leader_url") and "pursuit" in e for e in errors), errors
    errors = _errors({**BASE, "leader_url": "http://a:1", "leader_origin": [1, 0, float("nan")]})
    assert any(e.startswith("control.leader_origin") for e in errors), errors
    errors = _errors({**BASE, "leader_stale_s": 0.1})
    assert any(e.startswith("control.leader_stale_s") for e in errors), errors
