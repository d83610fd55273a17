"""Every reason code the daemon can report has a plain-language phrase, rendered right.

The codes are found two ways: read out of the controller's source (every string the
controller hands back as a reason), and produced by running the controller on
generated inputs. Either way, a new code without a phrase fails here.
"""

from __future__ import annotations

import ast
import inspect
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from relayd import brain, control, controller, recovery
from relayd.api.reasons import MINUS, comparison, describe, fmt_db, phrasebook
from relayd.controller import ControlInputs, ControlMemory, ControlParams, control_step
from relayd.estimator import SonarReading
from relayd.state import Mode, RelayState


def controller_reason_literals() -> set[str]:
    """Reason codes in relayd/controller.py, relayd/brain.py and relayd/control.py, plus every
    reason of relayd/recovery.py (`recovery.REASONS`, which tests/test_recovery.py checks
    the state machine against): `_stopped(state, "x", ...)`,
    `ControlOutput(l, r, state, "x", ...)`, `return False, "x"` and `reason = "x"`; for
    an f-string reason (`f"controller_error: {name}"`) the code before the colon."""
    trees = [ast.parse(inspect.getsource(module)) for module in (controller, brain, control)]
    found: set[str] = set(recovery.REASONS)

    def literal(node: ast.AST) -> None:
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            found.add(node.value)
        elif isinstance(node, ast.JoinedStr) and node.values and isinstance(node.values[0], ast.Constant):
            found.add(str(node.values[0].value).partition(":")[0].strip())

    for node in (n for tree in trees for n in ast.walk(tree)):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            if node.func.id == "_stopped" and len(node.args) >= 2:
                literal(node.args[1])
            if node.func.id == "ControlOutput" and len(node.args) >= 4:
                literal(node.args[3])
            for kw in node.keywords:
                if kw.arg == "reason":
                    literal(kw.value)
        elif isinstance(node, ast.Return) and isinstance(node.value, ast.Tuple) \
                and len(node.value.elts) == 2 and isinstance(node.value.elts[0], ast.Constant) \
                and isinstance(node.value.elts[0].value, bool):
            literal(node.value.elts[1])
        elif isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "reason" for t in node.targets):
            literal(node.value)
    return found


def test_the_source_scan_finds_the_controller_reasons() -> None:
    # Guards the scanner itself: if the controller's shape changed so that it finds
    # nothing, the test below would pass vacuously.
    found = controller_reason_literals()
    assert {"hold", "rear_weak", "leader_near", "no_sip", "manual", "driving", "shutdown",
            "controller_error", "scan_stale"} <= found


def test_every_reason_in_the_controller_source_has_a_phrase() -> None:
    codes = controller_reason_literals() | {RelayState().reason}  # "starting"
    missing = sorted(codes - set(phrasebook()))
    assert not missing, f"reason codes without a phrase in relayd/api/static/reasons.json: {missing}"


def test_every_phrase_is_for_a_code_that_exists() -> None:
    stale = sorted(set(phrasebook()) - controller_reason_literals() - {RelayState().reason})
    assert not stale, f"phrases for codes nothing produces: {stale}"


_age = st.one_of(st.none(), st.floats(0.0, 10.0))
_dbm = st.one_of(st.none(), st.floats(-100.0, -5.0))
_sonar = st.lists(st.builds(SonarReading, st.floats(-90, 90), st.one_of(st.none(), st.floats(0.05, 5.0))),
                  max_size=8).map(tuple)


@settings(max_examples=400, deadline=None)
@given(mode=st.sampled_from(list(Mode)), sip=_age, rssi=_age, servo=st.booleans(),
       bearing=st.one_of(st.none(), st.floats(-90, 90)), rl=_dbm, rb=_dbm, rear=_age, sonar=_sonar,
       lost=st.booleans(), left=st.one_of(st.none(), st.floats(-500, 500)),
       right=st.one_of(st.none(), st.floats(-500, 500)), manual_age=_age, latch=st.booleans())
def test_every_reason_the_controller_produces_has_a_phrase(
        mode: Mode, sip: float | None, rssi: float | None, servo: bool, bearing: float | None,
        rl: float | None, rb: float | None, rear: float | None, sonar: tuple[SonarReading, ...],
        lost: bool, left: float | None, right: float | None, manual_age: float | None,
        latch: bool) -> None:
    inputs = ControlInputs(mode=mode, sip_age_s=sip, rssi_age_s=rssi, scan_servo_ok=servo,
                           bearing_deg=bearing, prev_bearing_deg=None, rssi_leader_dbm=rl,
                           rssi_behind_dbm=rb, rear_age_s=rear, front_sonar=sonar, leader_lost=lost,
                           manual_left_mm_s=left, manual_right_mm_s=right, manual_age_s=manual_age)
    out = control_step(inputs, ControlParams(), ControlMemory(link_drive=latch))
    assert out.reason in phrasebook()
    doc = {"reason": out.reason, "mode": str(mode), "rssi_leader_dbm": rl, "rssi_behind_dbm": rb,
           "thresholds": {"threshold_l_dbm": -30.0, "threshold_b_dbm": -60.0, "hysteresis_db": 2.0}}
    assert describe(doc) != out.reason


THR = {"threshold_l_dbm": -30.0, "threshold_b_dbm": -60.0, "hysteresis_db": 2.0}


@pytest.mark.parametrize(("doc", "text"), [
    ({"reason": "rear_weak", "rssi_behind_dbm": -64.0, "thresholds": THR},
     f"stopped: the link behind is weak ({MINUS}64 dBm \u2264 {MINUS}60)"),
    # Inside the hysteresis band a stopped robot stays stopped: no false inequality.
    ({"reason": "rear_weak", "rssi_behind_dbm": -59.0, "thresholds": THR},
     f"stopped: the link behind is weak ({MINUS}59 dBm, drives again above {MINUS}58)"),
    ({"reason": "leader_near", "rssi_leader_dbm": -27.46, "thresholds": THR},
     f"stopped: close enough to the leader ({MINUS}27.5 dBm \u2265 {MINUS}30)"),
    ({"reason": "leader_near", "rssi_leader_dbm": -31.0, "thresholds": THR},
     f"stopped: close enough to the leader ({MINUS}31 dBm, drives again below {MINUS}32)"),
    ({"reason": "rear_weak", "rssi_behind_dbm": None, "thresholds": THR},
     "stopped: the link behind is weak"),
    ({"reason": "obstacle", "mode": "manual"}, "manual: an obstacle ahead, forward motion blocked"),
    ({"reason": "obstacle", "mode": "follow"}, "avoiding an obstacle ahead (slower, steering around it)"),
    ({"reason": "something_new"}, "something_new"),
    ({"reason": "controller_error: ZeroDivisionError"},
     "fault: the controller failed (a bug: see the log) (ZeroDivisionError)"),
    ({"reason": "toString"}, "toString"),
    ({"reason": "hold", "mode": "hold"}, "stopped: hold mode (an operator asked it to stand still)"),
])
def test_describe(doc: dict[str, object], text: str) -> None:
    assert describe(doc) == text


@pytest.mark.parametrize(("value", "text"), [
    (-64.0, f"{MINUS}64"), (-63.46, f"{MINUS}63.5"), (-63.44, f"{MINUS}63.4"), (0.0, "0"),
    (-0.04, "0"), (12.25, "12.3"), (-12.25, f"{MINUS}12.2"), (5.0, "5"),
])
def test_fmt_db_rounds_half_up_like_javascript(value: float, text: str) -> None:
    assert fmt_db(value) == text


def test_comparison_refuses_non_numbers() -> None:
    assert comparison("rear", {"rssi_behind_dbm": math.nan, "thresholds": THR}) is None
    assert comparison("rear", {"rssi_behind_dbm": True, "thresholds": THR}) is None
    with pytest.raises(ValueError, match="unknown detail"):
        comparison("sideways", {})
