"""The fleet page in a real headless Chromium, against three relays on fake rigs.

relay1 and relay2 are in-process daemons in follow mode; relay3 is a `relayd run`
subprocess, paused (SIGSTOP) and then killed mid-run. The page must show all three
live, the four hops of the chain, the two relays that have an origin on the map; show
relay3 as not answering, then unreachable, each within about 2 s, while the others'
data keeps its age (a silent relay stalls nothing); and hold-all must stop relay1 and
relay2 with their own tokens and say plainly that relay3 got nothing.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest

from relayd.api.app import start_api
from relayd.config.load import parse_settings
from relayd.core.vocab import Mode
from relayd.daemon import Daemon
from relayd.fakes.rig import FakeRig
from relayd.fleet.config import FleetSettings, Relay
from relayd.fleet.server import make_fleet_app
from tests.api.test_live_page_ops import PANTILT, SCAN, free_port, wait_http
from tests.support import running, until
from tests.system.test_live_page_browser import CHROMIUM_ARGS, _require_chromium
from tests.tools.test_run_cli import Relayd

pytestmark = pytest.mark.browser

#: The promise is 2 s (1 s relay timeout + 0.5 s poll + 0.5 s page poll); a loaded machine gets slack.
SHOWN_LIMIT_S = 5.0


def card(name: str, part: str) -> str:
    return f".relay-card[data-name='{name}'] .{part}"


async def test_fleet_page_three_relays_one_stopped_mid_run(tmp_path: Path) -> None:
    _require_chromium()
    from playwright.async_api import async_playwright

    timings: dict[str, float] = {}
    async with (
        FakeRig(tmp_path / "r1", name="relay1") as rig1,
        FakeRig(tmp_path / "r2", name="relay2") as rig2,
        FakeRig(tmp_path / "r3", name="relay3") as rig3,
    ):
        daemons = [
            Daemon(
                parse_settings(
                    rig.config_doc(
                        api_port=0, control={"mode": "follow"}, scan=SCAN, pantilt=PANTILT
                    )
                ),
                env=rig.env,
            )
            for rig in (rig1, rig2)
        ]
        port3 = free_port()
        config3 = rig3.write_config(
            secrets_in_files=True,
            api_port=port3,
            scan=SCAN,
            pantilt=PANTILT,
            control={"mode": "hold"},
            log={"format": "json"},
        )
        relayd3 = await Relayd.start("run", "-c", str(config3))
        try:
            async with running(daemons[0]), running(daemons[1]):
                await until(lambda: all(d.api_port for d in daemons), "both APIs to bind", 20.0)
                urls = [f"http://127.0.0.1:{d.api_port}" for d in daemons] + [
                    f"http://127.0.0.1:{port3}"
                ]
                await wait_http(urls[2] + "/status")
                settings = FleetSettings(
                    relays=(
                        Relay("relay1", urls[0], rig1.api_token, (0.0, 0.0, 0.0)),
                        Relay("relay2", urls[1], rig2.api_token, (-4.0, 0.0, 0.0)),
                        Relay("relay3", urls[2], rig3.api_token, None),
                    ),
                    poll_s=0.5,
                    timeout_s=1.0,
                )
                runner, fport = await start_api(make_fleet_app(settings), "127.0.0.1", 0)
                fleet_up = True
                try:
                    async with async_playwright() as pw:
                        browser = await pw.chromium.launch(
                            executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS
                        )
                        try:
                            page = await browser.new_page(viewport={"width": 1400, "height": 1000})
                            problems: list[str] = []
                            page.on("pageerror", lambda e: problems.append(str(e)))
                            await page.goto(f"http://127.0.0.1:{fport}/")
                            for name in ("relay1", "relay2", "relay3"):
                                await page.wait_for_selector(
                                    f"{card(name, 'link')}:text-is('live')", timeout=20_000
                                )
                            assert await page.locator(".hop").count() == 4
                            assert await page.text_content(card("relay3", "mode")) == "hold"
                            # relay3's fakes share this busy test process: a starved SIP
                            # can show a passing no-SIP fault first; hold mode must follow.
                            await page.wait_for_selector(
                                f"{card('relay3', 'reason')}:has-text('hold mode')", timeout=20_000
                            )
                            assert (
                                await page.text_content(card("relay1", "battery"))
                                == f"{rig1.robot.battery_v:.1f} V"
                            )
                            # The first hop is measured by relay1's front radio (the rig's -50 dBm).
                            await page.wait_for_function(
                                "() => document.querySelector(\".hop[data-index='0'] .rssi\").textContent"
                                " === '-50 dBm'",
                                timeout=10_000,
                            )
                            assert "Mb/s" in (
                                await page.text_content(".hop[data-index='0'] .rate") or ""
                            )
                            assert await page.locator("#map g.robot").count() == 2
                            assert "relay3: not on the map (no origin configured" in (
                                await page.text_content("#unplaced") or ""
                            )
                            await page.screenshot(
                                path=str(tmp_path / "fleet-live.png"), full_page=True
                            )

                            # relay3 paused: shown as not answering; the others stay fresh meanwhile.
                            relayd3.proc.send_signal(signal.SIGSTOP)
                            t0 = time.monotonic()
                            ages_s: list[float] = [0.0]

                            async def relay3_not_answering() -> bool:
                                # Each look also reads the healthy relays' data age.
                                for name in ("relay1", "relay2"):
                                    age = await page.text_content(card(name, "age")) or "99 s"
                                    ages_s.append(float(age.split()[0]))
                                return (
                                    await page.text_content(card("relay3", "link")) == "NO ANSWER"
                                )

                            await until(
                                relay3_not_answering,
                                "relay3 shown as NO ANSWER",
                                timeout_s=SHOWN_LIMIT_S,
                                poll_s=0.1,
                            )
                            worst_age = max(ages_s)
                            timings["paused_shown_s"] = time.monotonic() - t0
                            assert worst_age < 2.0, f"a healthy relay's data aged {worst_age} s"
                            assert await page.text_content(card("relay3", "state")) == "unknown"
                            assert "last known" in (
                                await page.text_content(card("relay3", "reason")) or ""
                            )

                            # relay3 killed mid-run: unreachable.
                            relayd3.proc.send_signal(signal.SIGCONT)
                            relayd3.proc.kill()
                            await relayd3.proc.wait()
                            t0 = time.monotonic()
                            await page.wait_for_selector(
                                f"{card('relay3', 'link')}:text-is('UNREACHABLE')",
                                timeout=int(SHOWN_LIMIT_S * 1000),
                            )
                            timings["killed_shown_s"] = time.monotonic() - t0
                            await page.wait_for_selector(
                                ".hop[data-index='3'] .rssi:text-is('unknown')", timeout=5_000
                            )

                            # Hold all: each relay with its own token; each result reported.
                            await page.click("#hold-all")
                            await page.wait_for_selector(
                                "#hold-results li[data-name='relay3']", timeout=10_000
                            )
                            results = {
                                n: await page.text_content(f"#hold-results li[data-name='{n}']")
                                for n in ("relay1", "relay2", "relay3")
                            }
                            assert results["relay1"] == "relay1: hold accepted"
                            assert results["relay2"] == "relay2: hold accepted"
                            assert (results["relay3"] or "").startswith(
                                "relay3: unreachable: hold NOT sent"
                            )
                            assert all(d.state.mode is Mode.HOLD for d in daemons)
                            for name in ("relay1", "relay2"):
                                await page.wait_for_selector(
                                    f"{card(name, 'mode')}:text-is('hold')", timeout=10_000
                                )
                                await page.wait_for_selector(
                                    f"{card(name, 'state')}:text-is('stopped')", timeout=10_000
                                )
                            await page.screenshot(
                                path=str(tmp_path / "fleet-held.png"), full_page=True
                            )
                            assert not problems, problems

                            # The fleet server itself gone: the page greys out and says so.
                            await runner.cleanup()
                            fleet_up = False
                            t0 = time.monotonic()
                            await page.wait_for_function(
                                "() => document.body.classList.contains('stale')",
                                timeout=int(SHOWN_LIMIT_S * 1000),
                            )
                            timings["fleet_server_gone_shown_s"] = time.monotonic() - t0
                            assert await page.is_visible("#stale-banner")
                        finally:
                            await browser.close()
                finally:
                    if fleet_up:
                        await runner.cleanup()
        finally:
            if relayd3.proc.returncode is None:
                relayd3.proc.send_signal(signal.SIGCONT)
            await relayd3.kill()
    print(f"fleet timings: {timings}")
