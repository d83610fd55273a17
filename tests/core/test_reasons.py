"""Every reason code the daemon can report has a plain-language phrase, rendered right.

The codes are found two ways: read out of the source of every relayd module (every
string handed to a `reason` parameter or field, or assigned to a `*reason` variable),
and produced by running the controller on generated inputs. Either way, a new code
without a phrase fails here, in whichever module it appears.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from relayd.api.reasons import MINUS, comparison, describe, fmt_db, phrasebook
from relayd.core.control.law import ControlInputs, ControlMemory, ControlParams, control_step
from relayd.core.recovery import machine as recovery
from relayd.core.recovery import state as recovery_state
from relayd.core.scan.estimator import SonarReading
from relayd.core.vocab import Mode, Reason
from relayd.runtime.state import RelayState

RELAYD = Path(recovery.__file__).resolve().parents[2]


def _reason_positions(trees: list[ast.Module]) -> dict[str, set[int | None]]:
    """name -> positions of its `reason` argument (None: keyword-only), for every function
    and every field class (dataclass, NamedTuple) that takes one: `stopped(state,
    reason, ...)`, `ControlOutput(l, r, state, reason, ...)`, `turn_cmd(act, s, p, rvel,
    reason)`; a set, as two modules may each have a `_zero`. A `reason=` that lands in
    `**fields` (a log line's field) is not a code."""
    out: dict[str, set[int | None]] = {}
    for node in (n for tree in trees for n in ast.walk(tree)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            names = [a.arg for a in (*node.args.posonlyargs, *node.args.args)]
            if names and names[0] in ("self", "cls"):
                names = names[1:]
            if "reason" in (a.arg for a in node.args.kwonlyargs):
                out.setdefault(node.name, set()).add(None)
        elif isinstance(node, ast.ClassDef):
            names = [
                s.target.id
                for s in node.body
                if isinstance(s, ast.AnnAssign)
                and isinstance(s.target, ast.Name)
                and "ClassVar" not in ast.unparse(s.annotation)
            ]
        else:
            continue
        if "reason" in names:
            out.setdefault(node.name, set()).add(names.index("reason"))
    return out


def reason_literals(trees: list[ast.Module]) -> set[str]:
    """The reason codes in these modules: a string given to a `reason` parameter or field
    (by keyword or by position), assigned to a name ending in `reason` (a field default
    included), or returned as `return False, "x"`; both arms of `a if c else b`; for an
    f-string reason (`f"controller_error: {name}"`) the code before the colon."""
    positions = _reason_positions(trees)
    found: set[str] = set()

    def literal(node: ast.AST | None) -> None:
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            found.add(node.value)
        elif (
            isinstance(node, ast.JoinedStr)
            and node.values
            and isinstance(node.values[0], ast.Constant)
        ):
            found.add(str(node.values[0].value).partition(":")[0].strip())
        elif isinstance(node, ast.IfExp):
            literal(node.body)
            literal(node.orelse)

    def is_reason(target: ast.AST) -> bool:
        return isinstance(target, ast.Name) and target.id.endswith("reason")

    for node in (n for tree in trees for n in ast.walk(tree)):
        if isinstance(node, ast.Call):
            func = node.func
            name = (
                func.id
                if isinstance(func, ast.Name)
                else func.attr
                if isinstance(func, ast.Attribute)
                else ""
            )
            if name not in positions:
                continue
            for pos in positions[name]:
                if pos is not None and len(node.args) > pos:
                    literal(node.args[pos])
            for kw in node.keywords:
                if kw.arg == "reason":
                    literal(kw.value)
        elif (
            isinstance(node, ast.Return)
            and isinstance(node.value, ast.Tuple)
            and len(node.value.elts) == 2
            and isinstance(node.value.elts[0], ast.Constant)
            and isinstance(node.value.elts[0].value, bool)
        ):
            literal(node.value.elts[1])
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(is_reason(t) for t in targets):
                literal(node.value)
    return found


def source_reason_codes() -> set[str]:
    """Every reason code in relayd's source, plus every reason of relayd/core/recovery/machine.py
    (`recovery.REASONS`, which tests/core/recovery/test_machine.py checks the state machine against)."""
    files = sorted(RELAYD.rglob("*.py"))
    trees = [_ReasonMembers().visit(ast.parse(p.read_text(encoding="utf-8"))) for p in files]
    return set(recovery_state.REASONS) | reason_literals(trees)


class _ReasonMembers(ast.NodeTransformer):
    """`Reason.BLOCKED` read as the literal it stands for, so the scan sees both spellings."""

    def visit_Attribute(self, node: ast.Attribute) -> ast.AST:
        if isinstance(node.value, ast.Name) and node.value.id == "Reason":
            return ast.copy_location(ast.Constant(Reason[node.attr].value), node)
        return self.generic_visit(node)


def test_the_source_scan_finds_the_controller_reasons() -> None:
    # Guards the scanner itself: if the code's shape changed so that it finds nothing,
    # the test below would pass vacuously. One code per shape it reads, per module.
    found = source_reason_codes()
    assert {
        "hold",
        "rear_weak",
        "leader_near",
        "no_sip",
        "manual",
        "driving",
        "shutdown",
        "controller_error",
        "recovery_error",
        "scan_stale",  # controller, brain, control
        "blocked",
        "avoiding",
        "rejoining",  # avoidance, avoidstate (positional and keyword)
        "rear_obstacle",  # breadcrumbs
    } <= found


def test_the_source_scan_reads_every_shape() -> None:
    tree = ast.parse(
        "def turn(a, b, reason): ...\n"
        "def note(event, **fields): ...\n"
        "async def stop(*, reason): ...\n"
        "class Cmd:\n    go: bool\n    reason: str = 'k_default'\n"
        "def f(x):\n"
        "    turn(1, 2, 'k_positional')\n"
        "    self.turn(1, 2, 'k_method')\n"
        "    Cmd(False, 'k_field')\n"
        "    Cmd(False, reason='k_keyword')\n"
        "    stop(reason='k_kwonly')\n"
        "    note('x', reason='a log field')\n"
        "    log.info('x', reason='another log field')\n"
        "    lost_reason = 'k_then' if x else 'k_else'\n"
        "    return False, f'k_fstring: {x}'\n"
    )
    assert _reason_positions([tree]) == {"turn": {2}, "stop": {None}, "Cmd": {1}}
    assert reason_literals([tree]) == {
        "k_default",
        "k_positional",
        "k_method",
        "k_field",
        "k_keyword",
        "k_kwonly",
        "k_then",
        "k_else",
        "k_fstring",
    }


def test_every_reason_in_the_controller_source_has_a_phrase() -> None:
    codes = source_reason_codes() | {RelayState().reason}  # "starting"
    missing = sorted(codes - set(phrasebook()))
    assert not missing, (
        f"reason codes without a phrase in relayd/api/static/reasons.json: {missing}"
    )


def test_every_phrase_is_for_a_code_that_exists() -> None:
    stale = sorted(set(phrasebook()) - source_reason_codes() - {RelayState().reason})
    assert not stale, f"phrases for codes nothing produces: {stale}"


_age = st.one_of(st.none(), st.floats(0.0, 10.0))
_dbm = st.one_of(st.none(), st.floats(-100.0, -5.0))
_sonar = st.lists(
    st.builds(SonarReading, st.floats(-90, 90), st.one_of(st.none(), st.floats(0.05, 5.0))),
    max_size=8,
).map(tuple)


@settings(max_examples=400, deadline=None)
@given(
    mode=st.sampled_from(list(Mode)),
    sip=_age,
    rssi=_age,
    servo=st.booleans(),
    bearing=st.one_of(st.none(), st.floats(-90, 90)),
    rl=_dbm,
    rb=_dbm,
    rear=_age,
    sonar=_sonar,
    lost=st.booleans(),
    left=st.one_of(st.none(), st.floats(-500, 500)),
    right=st.one_of(st.none(), st.floats(-500, 500)),
    manual_age=_age,
    latch=st.booleans(),
)
def test_every_reason_the_controller_produces_has_a_phrase(
    mode: Mode,
    sip: float | None,
    rssi: float | None,
    servo: bool,
    bearing: float | None,
    rl: float | None,
    rb: float | None,
    rear: float | None,
    sonar: tuple[SonarReading, ...],
    lost: bool,
    left: float | None,
    right: float | None,
    manual_age: float | None,
    latch: bool,
) -> None:
    inputs = ControlInputs(
        mode=mode,
        sip_age_s=sip,
        rssi_age_s=rssi,
        scan_servo_ok=servo,
        bearing_deg=bearing,
        prev_bearing_deg=None,
        rssi_leader_dbm=rl,
        rssi_behind_dbm=rb,
        rear_age_s=rear,
        front_sonar=sonar,
        leader_lost=lost,
        manual_left_mm_s=left,
        manual_right_mm_s=right,
        manual_age_s=manual_age,
    )
    out = control_step(inputs, ControlParams(), ControlMemory(link_drive=latch))
    assert out.reason in phrasebook()
    doc = {
        "reason": out.reason,
        "mode": str(mode),
        "rssi_leader_dbm": rl,
        "rssi_behind_dbm": rb,
        "thresholds": {"threshold_l_dbm": -30.0, "threshold_b_dbm": -60.0, "hysteresis_db": 2.0},
    }
    assert describe(doc) != out.reason


THR = {"threshold_l_dbm": -30.0, "threshold_b_dbm": -60.0, "hysteresis_db": 2.0}


@pytest.mark.parametrize(
    ("doc", "text"),
    [
        (
            {"reason": "rear_weak", "rssi_behind_dbm": -64.0, "thresholds": THR},
            f"stopped: the link behind is weak ({MINUS}64 dBm \u2264 {MINUS}60)",
        ),
        # Inside the hysteresis band a stopped robot stays stopped: no false inequality.
        (
            {"reason": "rear_weak", "rssi_behind_dbm": -59.0, "thresholds": THR},
            f"stopped: the link behind is weak ({MINUS}59 dBm, drives again above {MINUS}58)",
        ),
        (
            {"reason": "leader_near", "rssi_leader_dbm": -27.46, "thresholds": THR},
            f"stopped: close enough to the leader ({MINUS}27.5 dBm \u2265 {MINUS}30)",
        ),
        (
            {"reason": "leader_near", "rssi_leader_dbm": -31.0, "thresholds": THR},
            f"stopped: close enough to the leader ({MINUS}31 dBm, drives again below {MINUS}32)",
        ),
        (
            {"reason": "rear_weak", "rssi_behind_dbm": None, "thresholds": THR},
            "stopped: the link behind is weak",
        ),
        (
            {"reason": "obstacle", "mode": "manual"},
            "manual: an obstacle ahead, forward motion blocked",
        ),
        (
            {"reason": "obstacle", "mode": "follow"},
            "avoiding an obstacle ahead (slower, steering around it)",
        ),
        (
            {"reason": "blocked", "mode": "follow"},
            "stopped: hemmed in by obstacles, waiting until the way to the leader is open",
        ),
        ({"reason": "something_new"}, "something_new"),
        (
            {"reason": "controller_error: ZeroDivisionError"},
            "fault: the controller failed (a bug: see the log) (ZeroDivisionError)",
        ),
        ({"reason": "toString"}, "toString"),
        (
            {"reason": "hold", "mode": "hold"},
            "stopped: hold mode (an operator asked it to stand still)",
        ),
    ],
)
def test_describe(doc: dict[str, object], text: str) -> None:
    assert describe(doc) == text


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (-64.0, f"{MINUS}64"),
        (-63.46, f"{MINUS}63.5"),
        (-63.44, f"{MINUS}63.4"),
        (0.0, "0"),
        (-0.04, "0"),
        (12.25, "12.3"),
        (-12.25, f"{MINUS}12.2"),
        (5.0, "5"),
    ],
)
def test_fmt_db_rounds_half_up_like_javascript(value: float, text: str) -> None:
    assert fmt_db(value) == text


def test_comparison_refuses_non_numbers() -> None:
    assert comparison("rear", {"rssi_behind_dbm": math.nan, "thresholds": THR}) is None
    assert comparison("rear", {"rssi_behind_dbm": True, "thresholds": THR}) is None
    with pytest.raises(ValueError, match="unknown detail"):
        comparison("sideways", {})
