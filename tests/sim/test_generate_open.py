"""The generator's open kinds (hall, warehouse, mixed): valid worlds that are what their
names say. A file of its own so the test runner's workers share the generator's work."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from relayd.sim.generate import build
from tests.sim.test_generate import _check_valid


@pytest.mark.parametrize("kind", ["hall", "warehouse", "mixed"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_world_is_valid(seed: int, kind: str) -> None:
    _check_valid(seed, kind)


@pytest.mark.parametrize("kind", ["hall", "warehouse", "mixed"])
@settings(max_examples=3, deadline=None)
@given(seed=st.integers(min_value=0, max_value=10**6))
def test_sampled_open_kinds_are_valid(kind: str, seed: int) -> None:
    _check_valid(seed, kind)


def _spans(boxes: list, axis: int) -> list[tuple[float, float]]:
    return sorted((lo[axis], hi[axis]) for lo, hi in boxes)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_open_kinds_have_what_their_names_say(seed: int) -> None:
    """A hall has pillars (and up to seven pieces of furniture) and a back room; a warehouse has long racks with aisles of
    1.5-4 m between them and its goal in an aisle; a mixed building has both, behind an
    inner doorway. Every doorway is 0.8-1.4 m wide."""
    hall, _ = build("hall", seed)
    squares = [b for b in hall["boxes"] if math.isclose(b[1][0] - b[0][0], b[1][1] - b[0][1])]
    assert len(squares) >= 4 and len(hall["boxes"]) - len(squares) <= 7  # type: ignore[arg-type]
    for kind, doors in (("warehouse", 1), ("mixed", 2), ("hall", 2)):
        world, route = build(kind, seed)
        assert len(world["doors"]) == doors  # type: ignore[arg-type]
        for a, b in world["doors"]:  # type: ignore[attr-defined]
            assert 0.8 <= math.dist(a, b) <= 1.4
        if kind == "hall":
            continue
        racks = [b for b in world["boxes"] if b[1][1] - b[0][1] > 4 * (b[1][0] - b[0][0])]  # type: ignore[attr-defined]
        assert len(racks) >= 3
        xs = _spans(racks, 0)
        assert all(
            1.5 - 1e-9 <= b0 - a1 <= 4.0 + 1e-9 for (_, a1), (b0, _) in itertools.pairwise(xs)
        )
        gx, gy = route[-1]
        assert any(a1 < gx < b0 for (_, a1), (b0, _) in itertools.pairwise(xs))
        assert racks[0][0][1] < gy < racks[0][1][1]
