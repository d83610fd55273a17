"""Frame alignment of a leader relay's odometry: a wrong start pose corrected from bearings, or rejected."""

from __future__ import annotations

import math
import random

from relayd.core.trail.align import AlignParams, Frame, Sighting, align

TRUE = Frame(2.0, -1.0, 15.0)  # where the leader's frame really lies in ours
P = AlignParams()


def _sightings(frame: Frame, n: int, seed: int, sd_deg: float = 3.0) -> list[Sighting]:
    """The leader walks a corner in its frame; we follow 3 m behind-ish, looking at it."""
    rng = random.Random(seed)
    out = []
    for k in range(n):
        lx, ly = (0.3 * k, 0.0) if k < n // 2 else (0.3 * (n // 2), 0.3 * (k - n // 2))
        wx, wy = frame.apply((lx, ly))
        own = (wx - 3.0 + 0.05 * k, wy - 1.0 - 0.02 * k)
        b = math.degrees(math.atan2(wy - own[1], wx - own[0])) + rng.gauss(0.0, sd_deg)
        out.append(Sighting(own, b, (lx, ly)))
    return out


def test_a_wrong_start_pose_is_corrected_from_bearings() -> None:
    wrong = Frame(2.6, -0.4, 8.0)  # 0.85 m and 7 deg off
    got = align(wrong, _sightings(TRUE, 40, 1), P)
    assert got.accepted and got.why == "refined"
    err_before = math.dist(wrong.apply((6.0, 6.0)), TRUE.apply((6.0, 6.0)))
    err_after = math.dist(got.frame.apply((6.0, 6.0)), TRUE.apply((6.0, 6.0)))
    assert err_after < 0.5 * err_before
    assert abs(got.frame.phi_deg - TRUE.phi_deg) < 4.0
    assert got.rms_deg < 6.0


def test_an_alignment_the_antenna_disagrees_with_is_rejected() -> None:
    """A leader feed from some other robot (its path is not where the antenna hears it)."""
    sightings = _sightings(TRUE, 40, 2)
    mirrored = [Sighting(s.own_xy_m, s.bearing_world_deg + 60.0, s.leader_xy_m) for s in sightings]
    got = align(TRUE, mirrored, P)
    assert not got.accepted


def test_far_from_the_start_pose_is_rejected() -> None:
    far = Frame(-4.0, 5.0, 120.0)
    got = align(far, _sightings(TRUE, 40, 3), P)
    assert not got.accepted


def test_no_sightings_keep_the_prior() -> None:
    got = align(TRUE, [], P)
    assert got.accepted and got.frame == TRUE and got.why == "prior"
