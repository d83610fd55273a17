"""Never stuck without saying so: "trail_blocked" and its backoff."""

from __future__ import annotations

import dataclasses

from relayd.core.control.law import ControlInputs, ControlMemory, ControlParams, control_step
from relayd.core.scan.estimator import front_readings
from relayd.core.trail.blocked import BlockedParams, BlockedState, blocked_step
from relayd.core.vocab import DriveState, Mode

P = BlockedParams(after_s=30.0, progress_m=0.5, backoff_s=10.0, backoff_max_s=40.0)


def test_no_progress_for_after_s_stops_then_retries_on_a_doubling_backoff() -> None:
    st, waits = BlockedState(), []
    stopped_since = None
    t = 0.0
    while t < 400.0:
        st, stop = blocked_step(st, t, True, 5.0, P)
        if stop and stopped_since is None:
            stopped_since = t
        if not stop and stopped_since is not None:
            waits.append(round(t - stopped_since))
            stopped_since = None
        t += 0.5
    assert waits[:4] == [10, 20, 40, 40]


def test_progress_resets_the_watch_and_the_backoff() -> None:
    st, _ = blocked_step(BlockedState(), 0.0, True, 10.0, P)
    for k in range(1, 100):  # 0.1 m closer every second: never blocked
        st, stop = blocked_step(st, float(k), True, 10.0 - 0.1 * k, P)
        assert not stop
    st, _ = blocked_step(BlockedState(backoff_s=40.0), 0.0, True, 10.0, P)
    st, _ = blocked_step(st, 5.0, True, 9.0, P)
    assert st.backoff_s == 0.0
    # The escape ending by itself is a clean slate.
    st, stop = blocked_step(st, 6.0, False, 9.0, P)
    assert st == BlockedState() and not stop


def test_the_law_stops_a_fruitless_escape_on_trail_blocked() -> None:
    ranges: list[int | None] = [None] * 16
    ranges[3] = ranges[4] = 250  # a wall dead ahead, nearer than the stop distance
    params = ControlParams(pursuit="trail", trail_blocked=P)
    mem = ControlMemory(link_drive=True)
    reasons = []
    for k in range(400):  # 40 s at 10 Hz, the robot not getting anywhere
        ci = ControlInputs(
            mode=Mode.FOLLOW,
            sip_age_s=0.1,
            rssi_age_s=0.1,
            scan_servo_ok=True,
            bearing_deg=0.0,
            prev_bearing_deg=0.0,
            rssi_leader_dbm=-50.0,
            rssi_behind_dbm=-40.0,
            rear_age_s=1.0,
            front_sonar=front_readings(ranges),
            leader_lost=False,
            t_s=0.1 * k,
            odom=(0.0, 0.0, (3.0 * k) % 360.0),
            trail_steer_deg=0.0,
            trail_remaining_m=6.0,
        )
        out = control_step(ci, params, mem)
        mem = out.memory
        reasons.append(out.reason)
        if out.reason == "trail_blocked":
            assert out.state is DriveState.STOPPED and out.left_mm_s == out.right_mm_s == 0.0
    assert "avoiding" in reasons[:300]
    assert "trail_blocked" in reasons
    first = reasons.index("trail_blocked")
    assert 290 <= first <= 320  # after 30 s of escape without progress
    # The bearing pursuit is the paper's and today's: no such guard.
    bearing = dataclasses.replace(params, pursuit="bearing")
    out = control_step(ci, bearing, dataclasses.replace(mem, trail_block=BlockedState()))
    assert out.reason != "trail_blocked"
