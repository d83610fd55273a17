"""The udev rules, the example config and DEPLOY.md name the same devices.

A robot set up from the docs must work with the example config unchanged apart from
serials and MACs: the device paths and the interface name are parsed out of each file
and compared, so renaming one without the others fails here. The built-in defaults
(config and `relayd probe wifi`) use the same names, so leaving a key out is no trap.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RULES = ROOT / "config" / "99-relayd.rules"
EXAMPLE = ROOT / "config" / "relayd.toml"
DEPLOY = ROOT / "docs" / "DEPLOY.md"

#: Pololu Maestro USB product IDs: Micro Maestro 6, Mini Maestro 12, 18, 24 (vendor 1ffb).
MAESTRO_PIDS = {"0089", "008a", "008b", "008c"}

_TERM = re.compile(r'\s*([A-Z_]+(?:\{[^}]*\})?)\s*(==|!=|\+=|-=|:=|=)\s*"([^"]*)"\s*,?')


def parse_rules(text: str) -> list[dict[str, tuple[str, str]]]:
    """Each rule line as {key: (operator, value)}; comments and blank lines skipped."""
    rules = []
    for line in text.splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        terms: dict[str, tuple[str, str]] = {}
        pos = 0
        while pos < len(line):
            m = _TERM.match(line, pos)
            assert m, f"cannot parse udev rule at {line[pos:]!r}"
            terms[m.group(1)] = (m.group(2), m.group(3))
            pos = m.end()
        rules.append(terms)
    return rules


def _rule_with(rules: list[dict[str, tuple[str, str]]], key: str) -> dict[str, tuple[str, str]]:
    found = [r for r in rules if key in r]
    assert len(found) == 1, f"expected one rule with {key}, got {found}"
    return found[0]


def _symlinks(rules: list[dict[str, tuple[str, str]]]) -> dict[str, dict[str, tuple[str, str]]]:
    return {"/dev/" + r["SYMLINK"][1]: r for r in rules if "SYMLINK" in r}


def test_maestro_rule_matches_only_the_maestros() -> None:
    rules = parse_rules(RULES.read_text())
    servo = _symlinks(rules)["/dev/relay/servo"]
    assert servo["ATTRS{idVendor}"] == ("==", "1ffb")
    op, pids = servo["ATTRS{idProduct}"]
    assert op == "==" and set(pids.split("|")) == MAESTRO_PIDS
    # The command port, not the TTL port.
    assert servo["ENV{ID_USB_INTERFACE_NUM}"] == ("==", "00")


def test_example_config_uses_the_udev_names() -> None:
    rules = parse_rules(RULES.read_text())
    links = _symlinks(rules)
    net = _rule_with(rules, "NAME")
    config = tomllib.loads(EXAMPLE.read_text())
    assert (
        config["robot"]["port"] in links
        and links[config["robot"]["port"]]["ATTRS{idVendor}"][1] == "0403"
    )
    assert config["pantilt"]["port"] in links
    assert links[config["pantilt"]["port"]]["ATTRS{idVendor}"][1] == "1ffb"
    assert config["wifi"]["interface"] == net["NAME"][1]
    assert "XXXX" not in EXAMPLE.read_text()


def test_built_in_defaults_use_the_udev_names() -> None:
    from relayd.cli import build_parser
    from relayd.config.model import Settings

    rules = parse_rules(RULES.read_text())
    links = _symlinks(rules)
    name = _rule_with(rules, "NAME")["NAME"][1]
    defaults = Settings()
    assert defaults.wifi.interface == name
    assert defaults.robot.port in links and defaults.pantilt.port in links
    probe = build_parser().parse_args(["probe", "wifi"])
    assert probe.interface == name


def test_deploy_guide_uses_the_same_names() -> None:
    rules = parse_rules(RULES.read_text())
    config = tomllib.loads(EXAMPLE.read_text())
    deploy = DEPLOY.read_text()
    assert f"--port {config['robot']['port']} " in deploy
    assert f"--port {config['pantilt']['port']} " in deploy
    assert f"--interface {config['wifi']['interface']} " in deploy
    assert _rule_with(rules, "NAME")["NAME"][1] in deploy
    for link in _symlinks(rules):
        assert f"`{link}`" in deploy


def test_the_guide_installs_the_rules_once_filled_in_and_starts_the_service_after_bring_up() -> (
    None
):
    """The service once started (and enabled the motors) before any device was checked, and
    the rules were installed before the section that says how to fill them in."""
    deploy = DEPLOY.read_text()
    udev = deploy.index("## 2. udev names")
    fill = deploy.index("udevadm info -a -n /dev/ttyUSB0")
    bring_up = deploy.index("## 3. Bring-up")
    servo = deploy.index("## 4. Servo calibration")
    assert udev < fill < deploy.index("install -m 0644 config/99-relayd.rules") < bring_up
    assert deploy.count("config/99-relayd.rules /etc/udev") == 1
    assert deploy.count("systemctl enable --now relayd") == 1
    assert servo < deploy.index("systemctl enable --now relayd") < deploy.index("## 5.")
    readme = (ROOT / "README.md").read_text()
    assert readme.index("relayd check-config /etc/relayd/relayd.toml") < readme.index(
        "systemctl enable --now relayd"
    )
    assert readme.index("DEPLOY.md section 2") < readme.index("systemctl enable --now relayd")
