"""Config: the documented defaults, every error named by its key, secrets never printed."""

from __future__ import annotations

from pathlib import Path

import pytest

from relayd.cli import main
from relayd.config.load import load_settings, parse_settings
from relayd.config.model import ConfigError, SecretRef, Settings, resolve_secret

EXAMPLE = Path(__file__).resolve().parents[2] / "config" / "relayd.toml"


def test_defaults_are_the_specs() -> None:
    s = Settings()
    c = s.control
    assert (c.threshold_l_dbm, c.threshold_b_dbm, c.hysteresis_db) == (-30, -60, 2)
    assert (c.kp, c.kd, c.w1, c.w2, c.v_max_mm_s) == (1.0, 0.3, 10, 150, 400)
    assert (c.threshold_o_m, c.stop_distance_m, c.detect_range_m, c.gamma_o_m) == (
        0.8,
        0.3,
        3.0,
        1.0,
    )
    assert (c.alpha_db, c.beta_per_m, c.lost_rssi_dbm, c.manual_deadman_s) == (30, 1.0, -85, 0.5)
    assert (s.scan.samples, s.scan.width_deg, s.scan.gamma, s.scan.mode) == (25, 180, 10.0, "step")
    assert s.robot.lost_after_s == 0.5 and s.pantilt.limits_deg == (-90, 90)
    assert (s.api.bind, s.api.port) == ("0.0.0.0", 8080)


def test_example_config_has_every_key_and_is_valid(capsys: pytest.CaptureFixture[str]) -> None:
    settings = load_settings(EXAMPLE)
    data = settings.model_dump()
    # Every key of every section is written out in the example (so it documents them all).
    text = EXAMPLE.read_text()
    for section, values in data.items():
        if section == "ap":
            continue
        for key in values:
            # Optional keys with no default value are shown commented out.
            assert f"\n{key} =" in text or f"{key} = " in text, (
                f"{section}.{key} missing from the example config"
            )
    assert main(["check-config", str(EXAMPLE)]) == 0
    out = capsys.readouterr().out
    assert "[control]" in out and "threshold_l_dbm = -30" in out


def test_every_error_is_listed_with_its_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[control]\nkpp = 2\nkp = "fast"\nrear_link = "maybe"\n'
        "[robot]\nbaud = 1234\n[pantilt]\nscan_pulse_us = [1500, 1500, 2000]\n"
        '[ap.rear]\nurl = "ftp://x"\npassword_env = "A"\n'
    )
    assert main(["check-config", str(bad)]) == 2
    err = capsys.readouterr().err
    for key in (
        "control.kpp",
        "control.kp",
        "control.rear_link",
        "robot.baud",
        "pantilt.scan_pulse_us",
        "ap.rear.url",
    ):
        assert key in err, key


def test_cross_field_rules() -> None:
    with pytest.raises(ConfigError, match="stop_distance_m"):
        parse_settings({"control": {"stop_distance_m": 1.0}})
    with pytest.raises(ConfigError, match="differ"):
        parse_settings({"pantilt": {"scan_channel": 1, "link_channel": 1}})
    with pytest.raises(ConfigError, match="password_env or password_file"):
        parse_settings({"ap": {"rear": {"url": "http://192.0.2.1"}}})
    with pytest.raises(ConfigError, match=r"control\.kp"):
        parse_settings({"control": {"kp": float("nan")}})


def test_unreadable_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_settings(tmp_path / "missing.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[robot\nport = 1\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_settings(broken)


def test_secrets_from_env_or_file_and_never_rendered(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    ref = SecretRef("ap.rear.password_env", "PW", None)
    assert resolve_secret(ref, {"PW": "hunter2"}) == "hunter2"
    with pytest.raises(
        ConfigError, match=r"ap\.rear\.password_env: environment variable PW is not set"
    ):
        resolve_secret(ref, {})
    f = tmp_path / "pw"
    f.write_text("s3cret\n")
    assert resolve_secret(SecretRef("k", None, str(f)), {}) == "s3cret"
    monkeypatch.setenv("RELAYD_AP_REAR_PASSWORD", "hunter2-value")
    monkeypatch.setenv("RELAYD_API_TOKEN", "token-value")
    assert main(["check-config", str(EXAMPLE)]) == 0
    out = capsys.readouterr().out
    assert "hunter2-value" not in out and "token-value" not in out
    assert "RELAYD_AP_REAR_PASSWORD (set)" in out


def test_run_refuses_a_bad_config_before_touching_devices(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[robot]\nport = 5\n")
    assert main(["run", "-c", str(bad)]) == 2
    assert "robot.port" in capsys.readouterr().err


def test_api_token_file_replaces_the_default_token_env() -> None:
    first = {"control": {"rear_link": "ignore"}}
    s = parse_settings({**first, "api": {"token_file": "/etc/relayd/token"}})
    assert s.api.token_env is None and s.api.token_file == "/etc/relayd/token"
    assert parse_settings(first).api.token_env == "RELAYD_API_TOKEN"
    with pytest.raises(ConfigError, match="token_env or token_file"):
        parse_settings({**first, "api": {"token_env": "T", "token_file": "/etc/relayd/token"}})


def test_display_name_is_optional_and_bounded() -> None:
    assert Settings().robot.display_name is None
    s = parse_settings(
        {"robot": {"display_name": "relay 2 (east)"}, "control": {"rear_link": "ignore"}}
    )
    assert s.robot.display_name == "relay 2 (east)"
    for bad in ("", "x" * 65, 7):
        with pytest.raises(ConfigError) as info:
            parse_settings({"robot": {"display_name": bad}})
        assert any(e.startswith("robot.display_name") for e in info.value.errors), info.value.errors


def test_avoidance_keys_reach_the_escape_and_default_to_its_own() -> None:
    from relayd.config.params import control_params
    from relayd.core.avoid.state import AvoidParams
    from relayd.core.control.actuator import Actuator

    # The shipped defaults are the escape's code defaults (one set of numbers, not two).
    c = control_params(Settings())
    assert c.avoid == AvoidParams() and c.actuator == Actuator()
    alone = {"rear_link": "ignore"}
    tuned = control_params(
        parse_settings(
            {
                "control": alone,
                "avoidance": {
                    "max_escape_s": 120,
                    "max_escape_m": 15.5,
                    "max_turn_deg": 720,
                    "max_stray_m": 4.5,
                    "turn_rate_deg_s": 25,
                    "min_turn_deg_s": 12,
                },
            }
        )
    )
    a = tuned.avoid
    assert (a.max_escape_s, a.max_escape_m, a.max_turn_deg, a.turn_rate_deg_s) == (
        120,
        15.5,
        720,
        25,
    )
    assert a.max_stray_m == 4.5
    assert tuned.actuator.min_turn_deg_s == 12 and tuned.actuator.turn(3.0) == 12
    with pytest.raises(ConfigError, match=r"avoidance\.turn_rate_deg_s.*min_turn_deg_s"):
        parse_settings({"control": alone, "avoidance": {"turn_rate_deg_s": 6}})
    with pytest.raises(ConfigError, match=r"avoidance\.max_escape_s"):
        parse_settings({"control": alone, "avoidance": {"max_escape_s": 0}})
    with pytest.raises(ConfigError, match=r"avoidance\.blocked_retry_max_s.*blocked_retry_s"):
        parse_settings(
            {"control": alone, "avoidance": {"blocked_retry_s": 30, "blocked_retry_max_s": 20}}
        )
    # 0: a block holds (as before), whatever the longest wait says.
    held = parse_settings(
        {"control": alone, "avoidance": {"blocked_retry_s": 0, "blocked_retry_max_s": 0}}
    )
    assert held.avoidance.blocked_retry_s == 0
    with pytest.raises(ConfigError, match=r"did you mean 'max_turn_deg'"):
        parse_settings({"control": alone, "avoidance": {"max_turns_deg": 720}})


def test_search_keys_reach_the_lost_leaders_turn() -> None:
    from relayd.config.params import control_params
    from relayd.core.control.search import SearchParams

    alone = {"rear_link": "ignore"}
    assert control_params(Settings()).search == SearchParams()  # one set of defaults
    tuned = control_params(
        parse_settings({"control": {**alone, "search_turn": False, "search_turn_deg_s": 15}})
    )
    assert tuned.search == SearchParams(enabled=False, rate_deg_s=15.0)
    for bad in (0, 4, 91, "fast"):
        with pytest.raises(ConfigError, match=r"control\.search_turn_deg_s"):
            parse_settings({"control": {**alone, "search_turn_deg_s": bad}})
    with pytest.raises(ConfigError, match=r"did you mean 'search_turn'"):
        parse_settings({"control": {**alone, "search_turns": True}})
