"""Pursuit "trail" in the simulator: the trace carries each relay's trail source and
leader estimate, the estimate is near the true leader, and a "bearing" run's trace has none."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from bench.pursuit import calibrated
from relayd.runtime import vtime
from relayd.sim import plots
from relayd.sim.runner import SimRunner
from relayd.sim.scenario import load_scenario

pytestmark = pytest.mark.slow


@pytest.mark.timeout(120)
def test_the_trace_shows_the_trail_and_the_estimate_is_near_the_leader(tmp_path: Path) -> None:
    sc = load_scenario("box-dead-ahead")
    for pursuit in ("trail", "bearing"):
        run = sc.model_copy(
            update={"control": {**sc.control, **calibrated(sc), "pursuit": pursuit}}
        )
        runner = SimRunner(run, speed=None, seed=1, seconds=40.0)
        records = vtime.run(runner.run()).records
        relays = [x for r in records for x in r["relays"]]
        if pursuit == "bearing":
            assert all("trail" not in x for x in relays)
            continue
        shown = [(r, x["trail"]) for r in records for x in r["relays"] if x["trail"]["leader_xy_m"]]
        assert shown and {t["source"] for _, t in shown} <= {"estimate", "bearing"}
        errors = [
            math.dist(t["leader_xy_m"], (r["leader"]["x"], r["leader"]["y"]))
            for r, t in shown[-50:]
        ]
        sigmas = [t["leader_sigma_m"] for _, t in shown[-50:]]
        # The last 5 s: inside 3 of its own sigma every time (the 2-sigma share is the unit test's).
        assert all(e <= 3.0 * s for e, s in zip(errors, sigmas, strict=True)), (errors, sigmas)
        if plots.available():  # map.png draws the estimate beside the true path
            plots.plot_map(runner.world, records, tmp_path / "map.png")
            assert (tmp_path / "map.png").stat().st_size > 0
