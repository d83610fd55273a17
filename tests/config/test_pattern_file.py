"""`[scan] pattern_file`: checked when the config is, exit 2 naming the key; the brain gets the table."""

from __future__ import annotations

from pathlib import Path

import pytest

from relayd.cli import main
from relayd.config.load import parse_settings
from relayd.config.model import ConfigError
from relayd.config.params import brain_params
from relayd.core.scan.pattern import pattern_toml
from relayd.sim.antennas import family_pattern

BASE = '[control]\nrear_link = "ignore"\n'


def test_a_good_file_reaches_the_brain(tmp_path: Path) -> None:
    f = tmp_path / "p.toml"
    f.write_text(pattern_toml(family_pattern("yagi")))
    s = parse_settings({"control": {"rear_link": "ignore"}, "scan": {"pattern_file": str(f)}})
    p = brain_params(s).leader.pattern
    assert p is not None and p.beamwidth_deg() == pytest.approx(40.0, abs=0.5)
    assert brain_params(parse_settings({"control": {"rear_link": "ignore"}})).leader.pattern is None


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        (None, "cannot read"),
        ("[pattern]\nangles_deg = [0, 1, 2]\ngain_db = [0, 1]\n", "pattern.gain_db"),
        ("not toml [", "not valid TOML"),
    ],
)
def test_a_bad_file_is_exit_2_naming_the_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str | None, needle: str
) -> None:
    f = tmp_path / "p.toml"
    if content is not None:
        f.write_text(content)
    cfg = tmp_path / "relayd.toml"
    cfg.write_text(BASE + f'[scan]\npattern_file = "{f}"\n')
    assert main(["check-config", str(cfg)]) == 2
    err = capsys.readouterr()
    text = err.out + err.err
    assert "scan.pattern_file" in text and needle in text


def test_the_centroid_uses_no_pattern(tmp_path: Path) -> None:
    f = tmp_path / "p.toml"
    f.write_text(pattern_toml(family_pattern("yagi")))
    with pytest.raises(ConfigError, match="pattern_file needs estimator"):
        parse_settings(
            {
                "control": {"rear_link": "ignore"},
                "scan": {"estimator": "wca", "pattern_file": str(f)},
            }
        )
