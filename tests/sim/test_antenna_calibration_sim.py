"""`relayd calibrate antenna --from` a recording the daemon itself made, in the simulator.

A relay stands in hold mode, sweeping its full range, 8 m from a still leader, and
records its run (`relayd sim --record`); the simulator gives it the side-lobe Yagi of
its antenna family. The calibration read from that recording finds the Yagi's shape.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from relayd.calibrate.antenna import measure_pattern
from relayd.calibrate.antenna_sources import samples_from_recording
from relayd.runtime import vtime
from relayd.sim.runner import SimRunner
from relayd.sim.scenario import parse_scenario


@pytest.mark.slow
def test_a_daemons_recording_calibrates_the_yagi(tmp_path: Path) -> None:
    sc = parse_scenario(
        {
            "name": "antenna-calibration",
            "environment": "outdoor",
            "duration_s": 60.0,
            "settle_after_goal_s": 60.0,
            "command_center": {"x": -3.0, "y": 0.0},
            "leader": {"waypoints": [{"x": 8.0, "y": 0.0}]},
            "relays": 1,
            "relay": [{"name": "relay1", "x": 0.0, "y": 0.0, "theta_deg": 0.0}],
            "control": {"mode": "hold", "rear_link": "ignore"},
            "scan": {"pattern": "yagi", "window": "full"},
        }
    )
    vtime.run(
        SimRunner(sc, speed=None, seed=2, seconds=60.0, out_dir=tmp_path, record_dir=tmp_path).run()
    )
    samples = samples_from_recording(str(tmp_path / "relay1.mcap"))
    cal = measure_pattern(samples, distance_m=8.0, name="relay1")
    assert cal.sweeps >= 15
    assert cal.beamwidth_deg == pytest.approx(40.0, abs=6.0)
    assert cal.side_lobe_db is not None and cal.side_lobe_db == pytest.approx(-10.0, abs=3.0)
    assert abs(cal.squint_deg) <= 3.0
