"""docs/antenna-pattern-yagi.png: what a good `relayd calibrate antenna` pattern looks like.

A simulated calibration of the simulator's long Yagi (relayd/sim/antennas.py): 20 full
sweeps at each of four headings (the robot turned in place between them), LOS fading,
whole-dB readings, a node 8 m away; the same measurement tests/tools/calibrate/
test_antenna.py checks. `python bench/antenna_figure.py [OUT.png]` draws it again.
"""

from __future__ import annotations

import sys
from pathlib import Path

from relayd.calibrate.antenna import measure_pattern, plot_pattern
from relayd.calibrate.antenna_sources import samples_from_messages, sweep_messages
from relayd.sim.antennas import FAMILY

ROOT = Path(__file__).resolve().parent.parent


def main(out: str) -> int:
    msgs = sweep_messages(
        FAMILY["yagi"], seed=3, headings_deg=(0.0, 90.0, 180.0, 270.0), sweeps_per_heading=20
    )
    cal = measure_pattern(samples_from_messages(msgs), distance_m=8.0)
    if not plot_pattern(cal, out, "scan antenna: a long Yagi (simulated calibration)"):
        print("matplotlib is missing (pip install -e '.[sim]')", file=sys.stderr)
        return 1
    print(f"{out}: beamwidth {cal.beamwidth_deg:.1f} deg")
    return 0


if __name__ == "__main__":
    sys.exit(
        main(sys.argv[1] if len(sys.argv) > 1 else str(ROOT / "docs/antenna-pattern-yagi.png"))
    )
