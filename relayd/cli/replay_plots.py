"""Plots of a recording, drawn with the simulator's figures (`relayd.sim.plots`).

A recording has no ground truth, only what the robot knew: RSSI^l and the bearing
from each scan's estimate, RSSI^b as the brain saw it, and the path from the robot's
own odometry (drift included). The series are sampled like the simulator's trace
(10 per clock second) so the same figure code draws them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from relayd.core.events import Decision, RearLink, ScanResult, SipEvent
from relayd.record.reader import Recording
from relayd.sim import plots as sim_plots

TRACE_HZ = 10.0


def trace_records(rec: Recording) -> tuple[list[dict[str, Any]], list[float], list[float]]:
    """Sim-trace-like records (t from the recording's start) and the odometry path (m)."""
    name = (rec.robot or {}).get("name", "relay")
    t0 = rec.info.clock_t0
    rssi_l: float | None = None
    rssi_b: float | None = None
    bearing: float | None = None
    state, reason = "starting", ""
    xs: list[float] = []
    ys: list[float] = []
    records: list[dict[str, Any]] = []
    next_t: float | None = None
    for step in rec.steps:
        ev = step.event
        if isinstance(ev, SipEvent):
            xs.append(ev.sip.x_mm / 1000.0)
            ys.append(ev.sip.y_mm / 1000.0)
        for a in step.actions:
            if isinstance(a, ScanResult):
                rssi_l, bearing = a.estimate.rssi_leader_dbm, a.estimate.bearing_deg
            elif isinstance(a, RearLink):
                rssi_b = a.rssi_behind_dbm
            elif isinstance(a, Decision):
                state, reason = a.state.value, a.reason
        t = ev.t - t0
        if next_t is None or t >= next_t:
            records.append(
                {
                    "t": round(t, 3),
                    "relays": [
                        {
                            "name": name,
                            "rssi_l_dbm": rssi_l,
                            "rssi_b_dbm": rssi_b,
                            "bearing_deg": bearing,
                            "true_bearing_deg": None,
                            "state": state,
                            "reason": reason,
                        }
                    ],
                }
            )
            next_t = t + 1.0 / TRACE_HZ
    return records, xs, ys


def recorded_thresholds(rec: Recording) -> tuple[float, float]:
    """threshold_l and threshold_b as the recorded config set them (the lines the RSSI
    panel draws, as the simulator's does)."""
    from relayd.config.load import parse_settings

    control = parse_settings(rec.info.config).control
    return control.threshold_l_dbm, control.threshold_b_dbm


def plot_recording(rec: Recording, out: Path) -> list[Path]:
    """rssi_bearing.png and path.png into `out`; returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    records, xs, ys = trace_records(rec)
    name = (rec.robot or {}).get("name", "relay")
    files = [out / "rssi_bearing.png", out / "path.png"]
    sim_plots.plot_rssi_bearing(records, files[0], [recorded_thresholds(rec)])
    sim_plots.plot_paths(
        {name: (xs, ys)}, files[1], f"{name}: path from odometry ({rec.path.name})"
    )
    return files
