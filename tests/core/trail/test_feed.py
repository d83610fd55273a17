"""The leader relay's own path (relayd/core/trail/feed.py, keeper.py): aligned into our frame,
followed while fresh, the prior kept against the antenna's bias and its walls, corrected when
the bearings clearly disagree, rejected when nothing fits; stale: the estimate, then the bearing."""

from __future__ import annotations

import math
import random

from relayd.core.events import LeaderPath
from relayd.core.trail.align import Frame, frame_between
from relayd.core.trail.feed import (
    FEED_REJECTED,
    FEED_STALE,
    FEED_UP,
    FEED_WAITING,
    FeedParams,
    LeaderFeed,
)
from relayd.core.trail.keeper import (
    SOURCE_BEARING,
    SOURCE_ESTIMATE,
    SOURCE_FEED,
    TrailKeeper,
    TrailParams,
)

TRUE = Frame(1.5, 0.0, 0.0)  # the leader started 1.5 m ahead, facing the same way


def _leader_xy(t: float) -> tuple[float, float]:
    """The leader (its own frame) drives 0.3 m/s east for 20 s, then north."""
    return (0.3 * t, 0.0) if t <= 20.0 else (6.0, 0.3 * (t - 20.0))


def _answer(t: float, offset_s: float = 100.0) -> LeaderPath:
    """The leader's GET /path at our time t; its clock reads `offset_s` less than ours."""
    lt = t - offset_s
    points = tuple((k * 0.25 - offset_s, *_leader_xy(k * 0.25)) for k in range(int(t / 0.25) + 1))
    x, y = _leader_xy(t)
    return LeaderPath(t + 0.05, (lt, x, y, 0.0), points)


def _bearing(
    own: tuple[float, float], t: float, frame: Frame = TRUE, rng: random.Random | None = None
) -> float:
    wx, wy = frame.apply(_leader_xy(t))
    b = math.degrees(math.atan2(wy - own[1], wx - own[0]))
    return b + (0.0 if rng is None else rng.gauss(0.0, 3.0))


def _feed(prior: Frame, **kw: float) -> LeaderFeed:
    return LeaderFeed(FeedParams(prior=prior, **kw))  # type: ignore[arg-type]


def _drive(feed: LeaderFeed, until_s: float, bearing: object, own_at: object) -> None:
    """Answers every 0.5 s, a sighting every 1 s from where we stand then."""
    t = 0.0
    while t <= until_s:
        feed.on_path(_answer(t))
        if t % 1.0 == 0.0 and t >= 1.0:
            own = own_at(t)  # type: ignore[operator]
            feed.sight(t, own, bearing(own, t), 3.0)  # type: ignore[operator]
        t += 0.5


def test_frame_between_origins() -> None:
    f = frame_between((10.0, 5.0, 90.0), (10.0, 7.0, 180.0))
    assert math.isclose(f.tx_m, 2.0, abs_tol=1e-9) and math.isclose(f.ty_m, 0.0, abs_tol=1e-9)
    assert math.isclose(f.phi_deg, 90.0)


def test_the_path_is_mapped_into_our_frame_and_stops_short_of_the_leader() -> None:
    feed = _feed(Frame(1.0, 2.0, 90.0))
    assert feed.state(0.0) == FEED_WAITING and feed.trail(0.0, (0.0, 0.0)) is None
    feed.on_path(_answer(10.0))
    trail = feed.trail(10.1, (1.0, 2.0))
    assert trail is not None and feed.state(10.1) == FEED_UP
    # The leader's (3, 0) is our (1, 5); the head is 1.5 m short of it, on the path.
    assert math.dist(trail[-1].xy, (1.0, 3.5)) < 1e-6
    assert all(abs(p.x_m - 1.0) < 1e-9 for p in trail)


def test_a_stale_feed_is_not_followed_and_the_keeper_falls_back() -> None:
    keeper = TrailKeeper(TrailParams(pursuit="trail", feed=FeedParams(prior=TRUE, stale_s=2.0)))
    keeper.leader_path(_answer(10.0))
    pose = (0.0, 0.0, 0.0)
    got = keeper.steer(10.5, pose, ())
    assert got is not None and keeper.view().source == SOURCE_FEED
    # No estimate of ours yet: stale means the bearing.
    assert keeper.steer(12.1, pose, ()) is None
    v = keeper.view()
    assert v.source == SOURCE_BEARING and v.feed is not None and v.feed.state == FEED_STALE
    # An estimated trail of our own: stale means the estimate.
    for k in range(8):
        keeper.scan(13.0 + k, pose, 0.0, 3.0, -30.0, None)
    assert keeper.steer(21.0, pose, ()) is not None
    assert keeper.view().source == SOURCE_ESTIMATE
    # The leader answers again: its path leads once more.
    keeper.leader_path(_answer(22.0))
    keeper.steer(22.2, pose, ())
    assert keeper.view().source == SOURCE_FEED
    assert keeper.view().to_json()["feed"] == keeper.view().feed.to_json()  # type: ignore[union-attr]


def test_an_answer_whose_pose_does_not_move_on_goes_stale() -> None:
    feed = _feed(TRUE, stale_s=2.0)
    ans = _answer(5.0)
    feed.on_path(ans)
    for k in range(1, 6):  # the same pose again and again (the leader's daemon lost its robot)
        feed.on_path(LeaderPath(ans.t + k, ans.pose, ans.points))
    assert feed.state(ans.t + 5.0) == FEED_STALE


def test_sightings_are_matched_on_the_leader_clock() -> None:
    feed = _feed(TRUE)
    for t in (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0):
        feed.on_path(_answer(t))
    at = feed.leader_at(2.0)
    assert at is not None and math.dist(at, _leader_xy(2.0)) < 0.05


def test_a_right_prior_stands_against_bias_and_a_wall() -> None:
    """4 deg of antenna bias throughout and 25 deg off for a third of the time (a leader
    heard along the corridor round a corner): the start poses are kept, not fitted to it."""
    feed = _feed(TRUE)

    def biased(own: tuple[float, float], t: float) -> float:
        return _bearing(own, t) + 4.0 + (-25.0 if 14.0 <= t < 24.0 else 0.0)

    _drive(feed, 30.0, biased, lambda t: (max(0.0, 0.3 * t - 3.0), 0.0))
    assert feed.alignment is not None and feed.alignment.accepted
    assert feed.alignment.why == "prior" and feed.frame == TRUE


def test_a_wrong_start_pose_is_corrected_by_the_bearings() -> None:
    # 1.5 m and 10 deg off: 20 deg in the bearings (an error the antenna can see; a
    # metre along the line of sight it cannot, and the prior then stands).
    wrong = Frame(1.5, 1.5, 10.0)
    feed = _feed(wrong)
    rng = random.Random(3)
    _drive(feed, 40.0, lambda own, t: _bearing(own, t, rng=rng), lambda t: (0.3 * t - 1.0, -1.5))
    a = feed.alignment
    assert a is not None and a.accepted and a.why == "refined", a
    probe = (6.0, 6.0)
    assert math.dist(feed.frame.apply(probe), TRUE.apply(probe)) < 0.5 * math.dist(
        wrong.apply(probe), TRUE.apply(probe)
    )
    assert feed.state(40.1) == FEED_UP


def test_a_feed_the_antenna_disagrees_with_is_rejected_and_not_followed() -> None:
    """The feed is some other robot's (its path runs where the antenna never hears it)."""
    feed = _feed(TRUE)
    elsewhere = Frame(-3.0, 6.0, 150.0)
    _drive(feed, 30.0, lambda own, t: _bearing(own, t, elsewhere), lambda t: (0.0, 0.0))
    assert feed.alignment is not None and not feed.alignment.accepted
    assert feed.state(30.1) == FEED_REJECTED
    assert feed.trail(30.1, (0.0, 0.0)) is None
    keeper = TrailKeeper(TrailParams(pursuit="trail"))
    keeper.feed = feed
    keeper.steer(30.1, (0.0, 0.0, 0.0), ())
    view = keeper.view()
    assert view.source == SOURCE_BEARING and view.feed is not None
    assert view.feed.state == FEED_REJECTED
    assert view.feed.alignment in ("bearings_disagree", "too_far_from_prior")


def test_the_relay_joins_the_path_and_drops_what_it_passed() -> None:
    feed = _feed(TRUE)
    feed.on_path(_answer(30.0))  # the leader drove east 6 m and north 3 m
    first = feed.trail(30.0, (0.0, 0.0))
    assert first is not None and math.dist(first[0].xy, (1.5, 0.0)) < 0.3
    later = feed.trail(30.5, (5.0, 0.05))
    assert later is not None and later[0].x_m >= 4.5
    # Back at the start (a loop): the part already passed is not joined again.
    back = feed.trail(31.0, (1.5, 0.0))
    assert back is not None and back[0].x_m >= 4.5
