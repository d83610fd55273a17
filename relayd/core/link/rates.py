"""802.11 rate ladders: the standard's minimum receiver sensitivity of each PHY rate.

One copy for the three users: the simulator picks a hop's rate from its local mean
(relayd/sim/radio.py), `relayd calibrate` turns a wanted throughput into the signal
it needs (relayd/calibrate/fit.py), and the adaptive rear limit reads where on the
ladder a poll's rate sits (relayd/core/link/model.py).

Each ladder is (sensitivity dBm, PHY rate Mbit/s), fastest first. Real radios beat
these sensitivities by several dB, so only their *differences* are taken as given by
the link model; the absolute level is what it learns.
"""

from __future__ import annotations

from collections.abc import Mapping

Ladder = tuple[tuple[float, float], ...]

#: 802.11g OFDM receiver minimum sensitivity (dBm) -> PHY rate (Mbit/s), fastest first.
RATE_TABLE_80211G: Ladder = (
    (-65.0, 54.0),
    (-66.0, 48.0),
    (-70.0, 36.0),
    (-74.0, 24.0),
    (-77.0, 18.0),
    (-79.0, 12.0),
    (-81.0, 9.0),
    (-82.0, 6.0),
)
#: 802.11n, one spatial stream, 20 MHz, 800 ns guard interval: MCS7..MCS0 with the
#: standard's minimum sensitivities (IEEE 802.11-2012, table 20-22).
RATE_TABLE_80211N_1X1: Ladder = (
    (-64.0, 65.0),
    (-65.0, 58.5),
    (-66.0, 52.0),
    (-70.0, 39.0),
    (-74.0, 26.0),
    (-77.0, 19.5),
    (-79.0, 13.0),
    (-82.0, 6.5),
)
RATE_TABLES: Mapping[str, Ladder] = {
    "802.11g": RATE_TABLE_80211G,
    "802.11n-1x1": RATE_TABLE_80211N_1X1,
}


def ladder_of(rate_mbps: float) -> tuple[Ladder, int] | None:
    """The ladder holding this PHY rate and its index there (0 = fastest), or None."""
    for ladder in RATE_TABLES.values():
        for i, (_sens, rate) in enumerate(ladder):
            if abs(rate - rate_mbps) < 0.05:
                return ladder, i
    return None
