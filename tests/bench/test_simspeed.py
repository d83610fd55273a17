"""bench/simspeed.py: its cases parse, a real run is measured, and a difference fails it."""

from __future__ import annotations

import argparse
import math

import pytest

from bench import simspeed
from bench.simspeed import Case, Run


def test_cases_parse() -> None:
    assert Case.parse("convoy") == Case("convoy")
    assert Case.parse("drift:1:3:on") == Case("drift", 1, 3, "on")
    assert Case.parse("corridor::2") == Case("corridor", None, 2)
    assert Case.parse("drift:1:3:on").argv(simspeed.ROOT)[-4:] == [
        "--relays",
        "1",
        "--recovery",
        "on",
    ]
    for bad in ("", "x:1:1:maybe", "a:1:2:on:extra"):
        with pytest.raises(argparse.ArgumentTypeError):
            Case.parse(bad)


@pytest.mark.timeout(120)
def test_one_real_run_is_measured_and_digested() -> None:
    run = simspeed.run_case(Case("corridor", 0, 1), simspeed.ROOT)
    assert run.sim_s > 250.0  # corridor without relays: the person walks on until it breaks
    assert 0.0 < run.cpu_s < 120.0
    assert len(run.digest) == 12


def test_a_case_that_differs_between_the_trees_fails_the_bench(
    monkeypatch: pytest.MonkeyPatch, tmp_path, capsys
) -> None:
    def fake_run(case: Case, tree) -> Run:
        return Run(1.0, 0.5, 100.0, "aaaa" if tree == simspeed.ROOT else "bbbb")

    monkeypatch.setattr(simspeed, "run_case", fake_run)
    assert simspeed.main(["--cases", "convoy:2:1", "--against", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert "**NO**" in out and "1 case(s) DIFFER" in out
    monkeypatch.setattr(simspeed, "run_case", lambda case, tree: Run(1.0, 0.5, 100.0, "same"))
    assert simspeed.main(["--cases", "convoy:2:1", "--against", str(tmp_path)]) == 0
    assert "all cases byte-identical" in capsys.readouterr().out


def test_a_differing_case_names_the_outcomes_that_moved() -> None:
    a = {"goal_reached": True, "followers": [{"final_gap_m": 2.5, "collisions": 0}]}
    b = {"goal_reached": True, "followers": [{"final_gap_m": 2.6, "collisions": 0}]}
    assert simspeed.summary_differences(a, b) == ["followers[0].final_gap_m"]
    assert simspeed.summary_differences(a, a) == []
    assert simspeed.summary_differences(a, {**a, "collisions": 1}) == ["collisions"]


def test_a_differing_trace_names_its_fields_and_their_largest_difference() -> None:
    a = b'{"t":0.0,"relays":[{"x":1.0,"state":"driving"}]}\n{"t":0.1,"relays":[{"x":2.0}]}\n'
    b = b'{"t":0.0,"relays":[{"x":1.0,"state":"driving"}]}\n{"t":0.1,"relays":[{"x":2.5}]}\n'
    assert simspeed.trace_differences(a, a) == (0, {})
    assert simspeed.trace_differences(a, b) == (1, {"relays[].x": 0.5})
    c = a.replace(b'"driving"', b'"stopped"')
    assert simspeed.trace_differences(a, c) == (1, {"relays[].state": math.inf})
    assert simspeed.trace_differences(a, a.splitlines(keepends=True)[0])[0] == 1
