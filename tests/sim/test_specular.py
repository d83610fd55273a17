"""The specular sonar: smooth walls go silent past the grazing limit, corners still echo,
neighbours' pings cross over now and then (seeded)."""

from __future__ import annotations

import math
from typing import Any

from relayd.core.geometry import SONAR_POSES
from relayd.sim.scenario import parse_scenario
from relayd.sim.world import World

K = 3  # the transducer at (245, 27) mm heading +10 deg


def _world(walls: list[list[list[float]]], **sonar: Any) -> World:
    doc = {
        "name": "t",
        "command_center": {"x": -20, "y": 0},
        "leader": {"waypoints": [{"x": -10, "y": -10}]},
        "relays": 1,
        "relay": [{"name": "r", "x": 0, "y": 0}],
        "walls": [{"points": w} for w in walls],
        "sonar": sonar,
    }
    return World(parse_scenario(doc), seed=3)


def _reading(w: World, theta_deg: float, k: int = K) -> int:
    return w.sonar_mm(0, 0.0, 0.0, theta_deg)[k]


# A long smooth wall 2 m ahead (x = 2), its ends far outside every beam.
LONG_WALL = [[[2.0, -60.0], [2.0, 60.0]]]


def test_wall_echoes_inside_the_grazing_limit_and_not_past_it() -> None:
    plain = _world(LONG_WALL)
    spec = _world(LONG_WALL, specular=True, grazing_limit_deg=35.0, crosstalk_prob=0.0)
    heading = SONAR_POSES[K].heading_deg
    # The axis 34 deg from the wall's normal: the wall echoes, at the ordinary range.
    inside = 34.0 - heading
    assert _reading(spec, inside) == _reading(plain, inside) < 5000
    # 36 deg: the ping glances off; nothing else in reach, so no echo at all (5000 mm).
    outside = 36.0 - heading
    assert _reading(plain, outside) < 3000  # the old model still hears the wall
    assert _reading(spec, outside) == 5000
    # Head on, both models agree.
    assert _reading(spec, -heading) == _reading(plain, -heading)


def test_a_wall_end_in_the_beam_still_echoes_past_the_limit() -> None:
    # The same wall stopping at y = 1.5: its free end lies inside the 36-degree beam.
    short = [[[2.0, -60.0], [2.0, 1.5]]]
    spec = _world(short, specular=True, grazing_limit_deg=35.0, crosstalk_prob=0.0)
    theta = 36.0 - SONAR_POSES[K].heading_deg
    a = math.radians(theta)
    ox = 0.245 * math.cos(a) - 0.027 * math.sin(a)
    oy = 0.245 * math.sin(a) + 0.027 * math.cos(a)
    want_mm = round(1000 * math.hypot(2.0 - ox, 1.5 - oy))
    assert _reading(spec, theta) == want_mm


def test_crosstalk_is_seeded_and_reports_the_nearer_echo() -> None:
    # Facing away from the wall, transducer 3 hears nothing of its own; always cross-talk.
    kw = {"specular": True, "crosstalk_prob": 1.0}
    w1, w2 = _world(LONG_WALL, **kw), _world(LONG_WALL, **kw)
    quiet = _world(LONG_WALL, specular=True, crosstalk_prob=0.0)
    theta = -60.0
    got = [_reading(w1, theta, k) for k in range(16)]
    assert got == [_reading(w2, theta, k) for k in range(16)]  # same seed, same readings
    own = [_reading(quiet, theta, k) for k in range(16)]
    assert all(g <= o for g, o in zip(got, own, strict=True))
    assert any(g < o for g, o in zip(got, own, strict=True))  # some heard a neighbour
    never = _world(LONG_WALL, specular=True, crosstalk_prob=0.0)
    assert [_reading(never, theta, k) for k in range(16)] == own
