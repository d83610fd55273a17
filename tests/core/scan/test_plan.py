"""The next sweep's window and plan (relayd/core/scan/plan.py): pure, so plain and property tests."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from relayd.core.scan.plan import ScanParams, full_window, in_current_frame, next_window, sweep_plan
from relayd.core.scan.window import Window

SP = ScanParams(samples=13, width_deg=60.0, limits_deg=(-90.0, 90.0))


def test_lost_sweeps_the_whole_servo_range_whatever_the_model_plans() -> None:
    assert next_window(SP, True, Window(40.0, 20.0, 5), 40.0) == Window(0.0, 180.0, 13)
    assert full_window(ScanParams(limits_deg=(-60.0, 80.0), samples=7)) == Window(10.0, 140.0, 7)


def test_the_models_plan_wins_else_the_configured_width_on_the_bearing() -> None:
    assert next_window(SP, False, Window(40.0, 20.0, 5), -10.0) == Window(40.0, 20.0, 5)
    assert next_window(SP, False, None, -10.0) == Window(-10.0, 60.0, 13)
    assert next_window(SP, False, None, None) == Window(0.0, 60.0, 13)  # before the first scan


def test_a_sweep_goes_the_asked_way_and_is_shifted_inside_the_limits() -> None:
    up = sweep_plan(SP, Window(80.0, 60.0, 13), True).angles_deg
    down = sweep_plan(SP, Window(80.0, 60.0, 13), False).angles_deg
    assert up[0] == 30.0 and up[-1] == 90.0 and list(down) == list(reversed(up))


@given(st.floats(-180.0, 180.0), st.floats(-720.0, 720.0), st.floats(-720.0, 720.0))
def test_a_bearing_seen_from_a_new_heading_is_wrapped_and_turned_back(
    b: float, h0: float, h1: float
) -> None:
    now = in_current_frame(b, h0, h1)
    assert now is not None and -180.0 < now <= 180.0  # the one convention (core.geometry)
    diff = (now - (b - (h1 - h0))) % 360.0
    assert min(diff, 360.0 - diff) < 1e-6


def test_an_unknown_heading_leaves_the_bearing_as_measured() -> None:
    assert in_current_frame(None, 0.0, 10.0) is None
    assert in_current_frame(25.0, None, 10.0) == 25.0 and in_current_frame(25.0, 0.0, None) == 25.0
