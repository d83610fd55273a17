"""Config hardening: strict types, cross-key rules in the same pass, crash-free errors, suggestions."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from relayd.cli import main
from relayd.config.load import load_settings, parse_settings
from relayd.config.model import ConfigError

FIRST = {"control": {"rear_link": "ignore"}}  # a config valid without an [ap.rear]
REPO = Path(__file__).resolve().parents[2]


def _errors(doc: dict[str, object]) -> list[str]:
    with pytest.raises(ConfigError) as ei:
        parse_settings(doc)
    return ei.value.errors


@pytest.mark.parametrize(
    ("section", "key", "value"),
    [
        ("robot", "enabled", "off"),
        ("robot", "enabled", 1),
        ("control", "kp", "2.5"),
        ("wifi", "sample_hz", "20"),
        ("pantilt", "scan_channel", 0.0),
        ("robot", "lost_after_s", True),
        ("pantilt", "scan_pulse_us", ["1000", "1500", "2000"]),
    ],
)
def test_strict_types_are_errors_not_conversions(section: str, key: str, value: object) -> None:
    errors = _errors({**FIRST, section: {key: value}})
    assert any(e.startswith(f"{section}.{key}") for e in errors), errors


def test_an_int_is_a_float_and_toml_arrays_are_tuples() -> None:
    s = parse_settings(
        {
            **FIRST,
            "control": {"rear_link": "ignore", "kp": 2},
            "pantilt": {"limits_deg": [-80, 80], "scan_pulse_us": [900, 1500, 2100]},
        }
    )
    assert s.control.kp == 2.0 and isinstance(s.control.kp, float)
    assert s.pantilt.limits_deg == (-80.0, 80.0) and s.pantilt.scan_pulse_us == (900, 1500, 2100)


def test_schema_and_semantic_errors_in_one_pass(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[control]\nkp = "fast"\nthreshold_l_dbm = -70\nthreshold_b_dbm = 5\nlost_rssi_dbm = -20\n'
        "stop_distance_m = 1.0\n"
        '[pantilt]\nscan_channel = 1\nlink_channel = 1\nspeed_deg_s = "x"\n'
        '[api]\nbind = "localhost"\n'
    )
    assert main(["check-config", str(bad)]) == 2
    err = capsys.readouterr().err
    for key in (
        "control.kp",
        "control.threshold_b_dbm",
        "control.threshold_l_dbm",
        "control.lost_rssi_dbm",
        "control.threshold_o_m",
        "control.rear_link",
        "pantilt.link_channel",
        "pantilt.speed_deg_s",
        "api.bind",
    ):
        assert f"  {key}:" in err, f"{key} not reported:\n{err}"


def test_threshold_rules() -> None:
    assert any(
        "threshold_l_dbm: must be above threshold_b_dbm" in e
        for e in _errors(
            {"control": {"rear_link": "ignore", "threshold_l_dbm": -60, "threshold_b_dbm": -50}}
        )
    )
    assert any(
        e.startswith("control.lost_rssi_dbm")
        for e in _errors({"control": {"rear_link": "ignore", "lost_rssi_dbm": -30}})
    )
    assert any(
        e.startswith("control.threshold_l_dbm")
        for e in _errors({"control": {"rear_link": "ignore", "threshold_l_dbm": 3}})
    )
    # The paper's values pass.
    s = parse_settings(
        {"control": {"rear_link": "ignore", "threshold_l_dbm": -30, "threshold_b_dbm": -40}}
    )
    assert (s.control.threshold_l_dbm, s.control.threshold_b_dbm) == (-30, -40)


def test_rear_link_require_needs_an_enabled_rear_ap() -> None:
    assert any(e.startswith("control.rear_link") for e in _errors({}))
    rear = {"url": "http://192.0.2.1", "password_env": "PW"}
    assert any(
        e.startswith("control.rear_link")
        for e in _errors({"ap": {"rear": {**rear, "enabled": False}}})
    )
    assert parse_settings({"ap": {"rear": rear}}).control.rear_link == "require"


def test_every_non_finite_value_is_reported() -> None:
    nan, inf = float("nan"), float("inf")
    errors = _errors(
        {
            **FIRST,
            "control": {"rear_link": "ignore", "kp": nan, "w2": inf, "alpha_db": nan},
            "wifi": {"sample_hz": inf},
            "scan": {"gamma": -inf},
        }
    )
    for key in ("control.kp", "control.w2", "control.alpha_db", "wifi.sample_hz", "scan.gamma"):
        assert any(e.startswith(key) for e in errors), (key, errors)


def test_api_bind_must_be_an_ip_address() -> None:
    assert any(e.startswith("api.bind") for e in _errors({**FIRST, "api": {"bind": "robot.local"}}))
    assert parse_settings({**FIRST, "api": {"bind": "::"}}).api.bind == "::"


def test_mistyped_keys_get_a_suggestion() -> None:
    errors = _errors(
        {
            **FIRST,
            "control": {"rear_link": "ignore", "kpp": 2, "treshold_l_dbm": -30},
            "contrl": {},
            "ap": {"raer": {}},
        }
    )
    text = "\n".join(errors)
    assert "control.kpp: unknown key (did you mean 'kp'?)" in text
    assert "control.treshold_l_dbm: unknown key (did you mean 'threshold_l_dbm'?)" in text
    assert "contrl: unknown key (did you mean 'control'?)" in text
    assert "ap.raer: unknown key (did you mean 'rear'?)" in text
    assert "did you mean" not in _errors({**FIRST, "robot": {"zzzzzz": 1}})[0]


def test_non_utf8_config_names_the_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "latin1.toml"
    bad.write_bytes('[robot]\nbaud = 9600\nport = "/dev/caf\u00e9"\n'.encode("latin-1"))
    assert main(["check-config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "robot.port (line 3): not UTF-8 (byte 0xe9)" in err
    assert main(["run", "-c", str(bad)]) == 2
    assert "robot.port" in capsys.readouterr().err


def test_unreadable_secret_files_fail_check_config(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    empty = tmp_path / "token"
    empty.write_text("\n")
    cfg = tmp_path / "relayd.toml"
    cfg.write_text(
        f'[ap.rear]\nurl = "http://192.0.2.1"\npassword_file = "{tmp_path}/missing"\n'
        f'[api]\ntoken_file = "{empty}"\n'
    )
    assert main(["check-config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "ap.rear.password_file: cannot read" in err and "api.token_file" in err


def test_placeholder_device_path_is_a_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "relayd.toml"
    cfg.write_text(
        '[robot]\nport = "/dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A600XXXX-if00-port0"\n'
        '[control]\nrear_link = "ignore"\n'
    )
    assert main(["check-config", str(cfg)]) == 0
    err = capsys.readouterr().err
    assert "warning: robot.port:" in err and "placeholder" in err
    load_settings(cfg)  # a warning, not an error


def _run(cfg: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RELAYD_")}
    return subprocess.run(
        [sys.executable, "-m", "relayd", "run", "-c", str(cfg)],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        cwd=REPO,
    )


NO_DEVICES = (
    "[robot]\nenabled = false\n[pantilt]\nenabled = false\n[wifi]\nenabled = false\n"
    '[control]\nrear_link = "ignore"\n'
)


def test_run_exits_2_when_api_bind_is_not_an_address_here(tmp_path: Path) -> None:
    cfg = tmp_path / "relayd.toml"
    cfg.write_text(NO_DEVICES + '[api]\nbind = "192.0.2.1"\nport = 0\n')  # TEST-NET-1: never local
    r = _run(cfg)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "api.bind: 192.0.2.1 is not an address of this machine" in r.stderr
    assert "Traceback" not in r.stdout + r.stderr


def test_run_exits_2_when_api_port_is_taken(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        cfg = tmp_path / "relayd.toml"
        cfg.write_text(NO_DEVICES + f'[api]\nbind = "127.0.0.1"\nport = {port}\n')
        r = _run(cfg)
    assert r.returncode == 2, r.stdout + r.stderr
    assert f"api.port: {port} is already in use" in r.stderr
    assert "Traceback" not in r.stdout + r.stderr
