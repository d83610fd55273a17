"""The antenna pattern table and its file: interpolation, normalisation, metrics, errors naming keys."""

from __future__ import annotations

import math

import pytest

from relayd.core.scan.pattern import (
    AntennaPattern,
    PatternError,
    parse_pattern,
    pattern_toml,
    sampled,
)


def test_interpolates_normalises_and_floors_beyond_a_partial_table() -> None:
    p = AntennaPattern((-90.0, 0.0, 90.0), (-7.0, 3.0, -17.0), "t")
    assert p.gain_db_table == (-10.0, 0.0, -20.0)  # normalised to its peak
    assert p.gain_db(0.0) == pytest.approx(0.0)
    assert p.gain_db(45.0) == pytest.approx(-10.0)
    assert p.gain_db(-45.0) == pytest.approx(-5.0)
    # Beyond the measured -90..90: the lowest level measured, not a made-up lobe.
    assert not p.full_circle
    assert p.gain_db(150.0) == pytest.approx(-20.0)
    assert p.gain_db(-170.0) == pytest.approx(-20.0)


def test_a_full_circle_wraps_across_180() -> None:
    p = AntennaPattern((-170.0, 0.0, 170.0), (-10.0, 0.0, -30.0))
    assert p.full_circle
    assert p.gain_db(180.0) == pytest.approx(-20.0)  # halfway from 170 (-30) to 190 (-10)
    assert p.gain_db(-180.0) == pytest.approx(-20.0)


def test_metrics_of_a_known_shape() -> None:
    def shape(a: float) -> float:
        x = abs(math.remainder(a, 360.0))
        main = -12.0 * (x / 40.0) ** 2
        side = -10.0 - 12.0 * ((x - 60.0) / 15.0) ** 2
        back = -15.0 - 12.0 * ((180.0 - x) / 40.0) ** 2
        return max(main, side, back, -25.0)

    p = sampled(lambda a: shape(a - 8.0), "squinted yagi")
    assert p.peak_deg() == pytest.approx(8.0)
    assert p.beamwidth_deg() == pytest.approx(40.0, abs=0.3)
    assert p.front_to_back_db() == pytest.approx(15.0, abs=0.1)
    assert p.side_lobe_db() == pytest.approx(-10.0, abs=0.1)
    lo, hi = p.main_lobe_deg()
    assert 8.0 - 55.0 < lo < 8.0 - 40.0 and 8.0 + 40.0 < hi < 8.0 + 55.0


def test_file_round_trip_keeps_the_table_and_conditions() -> None:
    p = AntennaPattern((-90.0, -45.0, 0.0, 45.0, 90.0), (-20.0, -6.0, 0.0, -5.0, -18.0), "relay1")
    text = pattern_toml(p, {"distance_m": 8.0, "node": 'the "CC" AP'}, comment="a comment")
    q = parse_pattern(text)
    assert q.angles_deg == p.angles_deg and q.gain_db_table == p.gain_db_table
    assert q.name == "relay1"
    assert dict(q.conditions) == {"distance_m": "8.0", "node": 'the "CC" AP'}


def test_a_symmetric_file_is_mirrored() -> None:
    q = parse_pattern(
        "[pattern]\nsymmetric = true\nangles_deg = [0, 45, 90, 180]\ngain_db = [0, -3, -12, -20]\n"
    )
    assert q.angles_deg == (-180.0, -90.0, -45.0, 0.0, 45.0, 90.0, 180.0)
    assert q.gain_db(-45.0) == pytest.approx(-3.0) == q.gain_db(45.0)


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("[pattern]\nangles_deg = [0, 1, 2]\ngain_db = [0, 1]\n", "pattern.gain_db"),
        ("[pattern]\nangles_deg = [0, 2, 1]\ngain_db = [0, 1, 2]\n", "pattern.angles_deg"),
        ("[pattern]\nangles_deg = [0, 1, 200]\ngain_db = [0, 1, 2]\n", "pattern.angles_deg"),
        ('[pattern]\nangles_deg = [0, 1, 2]\ngain_db = [0, "x", 2]\n', "pattern.gain_db[1]"),
        ("[pattern]\nangles_deg = [0, 1, 2]\ngain_db = [0, 1, 2]\nwhat = 1\n", "pattern.what"),
        ("[pattern]\nformat = 9\nangles_deg = [0, 1, 2]\ngain_db = [0, 1, 2]\n", "pattern.format"),
        ("[other]\n", "[pattern]"),
        ("[pattern\n", "not valid TOML"),
    ],
)
def test_a_bad_file_names_the_key(text: str, key: str) -> None:
    with pytest.raises(PatternError, match=key.replace("[", r"\[").replace("]", r"\]")):
        parse_pattern(text)
