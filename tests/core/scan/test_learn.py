"""The antenna pattern learnt online: it converges on sure scans, refuses unsure ones, shows progress."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.brainrig import BrainRig, still
from relayd.core.scan.leader import TrackingModel
from relayd.core.scan.learn import LearnParams, PatternLearner, prior_db
from relayd.sim.antennas import FAMILY, cos_n

FULL = [-90.0 + 7.5 * i for i in range(25)]


def _scan(gain: object, bearing: float, rng: random.Random, level: float = -50.0) -> list[float]:
    """Whole-dB readings with +-1 dB of jitter, as real adapters report."""
    g = gain if callable(gain) else FAMILY[str(gain)]
    return [float(round(level + g(bearing - a) + rng.uniform(-1.0, 1.0))) for a in FULL]


def _teach(learner: PatternLearner, gain: object, scans: int, seed: int) -> None:
    rng = random.Random(seed)
    for _ in range(scans):
        b = rng.uniform(-55.0, 55.0)
        # The level wanders from scan to scan (distance, shadowing): only shapes are learnt.
        assert learner.add(FULL, _scan(gain, b, rng, rng.uniform(-70.0, -40.0)), b, 1.0)


@settings(max_examples=15, deadline=None)
@given(
    beamwidth=st.floats(30.0, 90.0),
    depth=st.floats(10.0, 30.0),
    seed=st.integers(0, 10_000),
)
def test_sure_scans_teach_the_true_main_lobe_within_1_db(
    beamwidth: float, depth: float, seed: int
) -> None:
    gain = cos_n(beamwidth, -depth)
    learner = PatternLearner()
    _teach(learner, gain, 120, seed)
    table = learner.pattern()
    # The main lobe: down to 10 dB (or the floor, for a shallow one) either side.
    edge = next(x for x in range(181) if gain(x) <= max(-10.0, -depth + 1.0))
    worst = max(abs(table.gain_db(x) - gain(x)) for x in range(-edge, edge + 1))
    assert worst <= 1.0, (worst, edge)
    assert learner.ready
    assert learner.status().scans == 120


@settings(max_examples=30, deadline=None)
@given(
    bearing=st.floats(-180.0, 180.0),
    sd=st.floats(0.0, 50.0),
    seed=st.integers(0, 1000),
)
def test_an_unsure_scan_never_enters(bearing: float, sd: float, seed: int) -> None:
    p = LearnParams()
    learner = PatternLearner(p)
    _teach(learner, "builtin", 5, seed)
    before = learner.pattern()
    scans = learner.scans
    rng = random.Random(seed)
    sure = sd <= p.sure_sd_deg and -90.0 + p.edge_margin_deg <= bearing <= 90.0 - p.edge_margin_deg
    took = learner.add(FULL, _scan("shallow", bearing, rng), bearing, sd)
    if not sure:
        assert not took
        assert learner.scans == scans
        assert learner.pattern().gain_db_table == before.gain_db_table


def test_before_any_scan_the_table_is_the_built_in_lobe_and_not_ready() -> None:
    learner = PatternLearner(beamwidth_deg=None)
    learner.set_prior_beamwidth(60.0)
    t = learner.pattern()
    for x in (0.0, 15.0, 30.0, 45.0, 120.0):
        assert t.gain_db(x) == pytest.approx(prior_db(x, 60.0, -20.0), abs=0.3)
    assert learner.status().to_json() == {
        "scans": 0,
        "refused": 0,
        "coverage_deg": 0.0,
        "ready": False,
    }
    # Not ready before `ready_scans`, however good the scans.
    _teach(learner, "shallow", LearnParams().ready_scans - 1, 3)
    assert not learner.ready
    _teach(learner, "shallow", 40, 4)
    assert learner.status().ready
    # Once data has entered, the prior is not reshaped under it.
    table = learner.pattern().gain_db_table
    learner.set_prior_beamwidth(20.0)
    assert learner.pattern().gain_db_table == table


def test_a_bin_forgets_so_a_changed_antenna_is_relearnt() -> None:
    learner = PatternLearner(LearnParams(max_weight=20.0))
    _teach(learner, cos_n(90.0, -20.0), 60, 1)
    _teach(learner, cos_n(40.0, -20.0), 200, 2)
    assert learner.pattern().beamwidth_deg() == pytest.approx(40.0, abs=3.0)


def test_bad_input_is_named() -> None:
    with pytest.raises(ValueError, match="bin_deg"):
        LearnParams(bin_deg=7.0)
    with pytest.raises(ValueError, match="RSSI"):
        PatternLearner().add(FULL, [-50.0], 0.0, 1.0)


def test_the_relay_learns_its_shallow_antenna_standing_still_and_fits_with_it() -> None:
    """The whole brain: a still leader at 20 deg, the shallow lobe the parabola misjudges."""
    b = 20.0
    leader = still(5.0 * math.cos(math.radians(b)), 5.0 * math.sin(math.radians(b)))
    rig = BrainRig(
        scan={"estimator": "lobe", "window": "adaptive", "learn_pattern": True},
        leader=leader,
        pattern=FAMILY["shallow"],
        jitter_db=1.0,
        jitter_seed=5,
    )
    rig.start()
    rig.run_scans(40)
    model = rig.brain.scans.model
    assert isinstance(model, TrackingModel)
    status = rig.brain.scans.pattern_learned()
    assert status is not None and status["ready"] is True, status
    assert model.pattern is not None
    # What it learnt is the shallow lobe's main lobe (relative to the track's bearing).
    truth = FAMILY["shallow"]
    worst = max(abs(model.pattern.gain_db(x) - truth(x)) for x in range(-30, 31))
    assert worst <= 1.5, worst
    assert abs(rig.results[-1][1].estimate.bearing_deg - b) <= 2.0


def test_status_shows_how_far_the_learnt_pattern_has_come() -> None:
    import json

    from relayd.api.openapi import STATUS_SCHEMA
    from relayd.api.status import Status
    from relayd.runtime.state import RelayState

    learner = PatternLearner()
    _teach(learner, "builtin", 20, 1)
    learner.add(FULL, [-50.0] * len(FULL), 0.0, 30.0)  # unsure: refused
    st = RelayState()
    st.pattern_source = lambda: learner.status().to_json()
    doc = st.snapshot(1.0)
    status = Status.model_validate_json(json.dumps(doc), strict=True)
    assert status.pattern_learned is not None
    assert status.pattern_learned.scans == 20 and status.pattern_learned.refused == 1
    assert status.pattern_learned.coverage_deg > 200.0 and status.pattern_learned.ready
    props = STATUS_SCHEMA["properties"]["pattern_learned"]
    assert set(props["properties"]) == {"scans", "refused", "coverage_deg", "ready"}
    assert props.get("nullable") is True
    # Not learning (the default): null.
    assert (
        Status.model_validate_json(json.dumps(RelayState().snapshot(0.0))).pattern_learned is None
    )


def test_learn_pattern_is_off_by_default_and_needs_the_tracking_estimator() -> None:
    from pydantic import ValidationError

    from relayd.config.model import Settings
    from relayd.config.params import brain_params

    assert not Settings.model_validate({}).scan.learn_pattern
    assert not brain_params(Settings.model_validate({})).leader.learn_pattern
    on = Settings.model_validate({"scan": {"learn_pattern": True}})
    assert brain_params(on).leader.learn_pattern
    with pytest.raises(ValidationError, match="learn_pattern needs estimator"):
        Settings.model_validate({"scan": {"learn_pattern": True, "estimator": "wca"}})


@pytest.mark.parametrize("name", ["builtin", "shallow", "patch", "deep"])
def test_a_table_known_only_in_part_is_a_bound_beyond_and_the_limits_hold(name: str) -> None:
    """What the learner hands the fit: the lobe within +-60 deg, beyond it only a bound.
    Taken as data, a wrong continuation (8 dB under the edge) drags the fit at the servo
    limits; as a bound (`known_deg`), one scan's fit holds within 5 deg everywhere."""
    from relayd.core.scan.pattern import AntennaPattern
    from relayd.core.scan.patternfit import fit_pattern

    g = FAMILY[name]
    angles = tuple(-179.0 + 2.0 * i for i in range(180))
    edge = 60.0
    wrong = tuple(g(a) if abs(a) <= edge else g(edge) - 8.0 for a in angles)
    bound = tuple(g(a) if abs(a) <= edge else g(edge) for a in angles)
    as_data = AntennaPattern(angles, wrong, "data")
    as_bound = AntennaPattern(angles, bound, "bound", known_deg=(-edge, edge))
    assert as_bound.known(30.0) and not as_bound.known(70.0) and as_data.known(70.0)
    rng = random.Random(3)
    worst_data = worst_bound = 0.0
    for b in range(-85, 86, 10):
        ys = _scan(g, float(b), rng)
        fd, fb = fit_pattern(FULL, ys, as_data), fit_pattern(FULL, ys, as_bound)
        assert fb is not None
        worst_bound = max(worst_bound, abs(fb.bearing_deg - b))
        worst_data = max(worst_data, 99.0 if fd is None else abs(fd.bearing_deg - b))
    assert worst_bound <= 5.0, worst_bound
    assert worst_data > worst_bound
