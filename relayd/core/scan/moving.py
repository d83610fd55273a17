"""A fast-moving leader's scan with a known pattern: the main-lobe parabola, moved to the leader.

`relayd.core.scan.leader.TrackingModel` matches the measured (or learnt) pattern to a still
leader's scan (relayd/core/scan/patternfit.py). A leader crossing the relay's front fast
is different: its scan is carried into the leader's frame by the tracking filter's rate,
which is only estimated, so the lobe comes stretched or squeezed; a fixed shape matched
to it takes that for a shift, with a small sd, where the parabola's free curvature
absorbs it (docs/CONTROL.md 10.6 has the figures). Pure: no clock, no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from relayd.core.scan.bearing import LobeFit, LobeParams, fit_main_lobe
from relayd.core.scan.pattern import AntennaPattern


def lobe_centre_deg(pattern: AntennaPattern) -> float:
    """The off-axis angle midway between the pattern's 3 dB points: where a parabola fitted
    to its lobe is centred (the peak for a symmetric lobe; a squinted or lopsided lobe's
    parabola sits there, not on the leader). 0 when the pattern never falls 3 dB."""
    left, right = pattern.half_widths_deg()
    if left is None or right is None:
        return 0.0
    return pattern.peak_deg() + (right - left) / 2.0


def fit_moving(
    angles_deg: Sequence[float],
    rssi_dbm: Sequence[float],
    pattern: AntennaPattern,
    lobe: LobeParams,
    centre_deg: float | None = None,
) -> LobeFit | None:
    """The parabola's fit of the scan with the pattern's beamwidth as its curvature prior,
    its centre moved by `centre_deg` (default `lobe_centre_deg(pattern)`) to the leader."""
    fit = fit_main_lobe(angles_deg, rssi_dbm, lobe, beamwidth_prior_deg=pattern.beamwidth_deg())
    if fit is None:
        return None
    shift = lobe_centre_deg(pattern) if centre_deg is None else centre_deg
    return replace(fit, bearing_deg=fit.bearing_deg + shift)
