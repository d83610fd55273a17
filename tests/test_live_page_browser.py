"""The live page in a real headless Chromium (Debian's /usr/bin/chromium via Playwright).

The page must load with no network but the robot's own, show the state, and redraw the
polar plot when a new scan arrives over /events, without a reload. Under CI=true a
missing chromium is a failure; locally it is a skip.
"""

from __future__ import annotations

import os
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from drivers.clock import Clock
from relayd.api import make_app, start_api
from relayd.api.demo import DemoControls, populate, synthetic_scan
from relayd.state import DriveState, RelayState

pytestmark = pytest.mark.browser

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]


def _require_chromium() -> None:
    if CHROMIUM.exists():
        return
    message = f"{CHROMIUM} is missing (apt-get install chromium)"
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail(message)
    pytest.skip(message)


@pytest.fixture
async def served() -> AsyncIterator[tuple[str, RelayState, Clock]]:
    clock = Clock()
    state = RelayState()
    populate(state, clock)
    runner, port = await start_api(make_app(state, DemoControls(state), clock=clock, token=None),
                                   "127.0.0.1", 0)
    try:
        yield f"http://127.0.0.1:{port}", state, clock
    finally:
        await runner.cleanup()


async def test_live_page_shows_state_and_redraws_on_new_scan(
        served: tuple[str, RelayState, Clock], tmp_path: Path) -> None:
    _require_chromium()
    from playwright.async_api import async_playwright

    url, state, clock = served
    problems: list[str] = []
    requests: list[str] = []
    async with async_playwright() as pw:
        browser = await pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            page = await browser.new_page(viewport={"width": 1400, "height": 1000})
            page.on("console", lambda m: problems.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: problems.append(str(e)))
            page.on("request", lambda r: requests.append(r.url))
            await page.goto(url + "/")

            await page.wait_for_function(
                "document.getElementById('drive-state').textContent === 'driving'", timeout=10_000)
            assert await page.text_content("#robot-name") == "relay-demo"
            assert await page.text_content("#mode") == "follow"
            assert (await page.text_content("#reason") or "").startswith("demo:")
            assert await page.text_content("#rssi-b") == "-52.0 dBm"
            assert await page.text_content("#thr-l") == "-30 dBm"
            assert await page.locator("#scan-points circle").count() == 25
            assert await page.locator("#sonar-rays line").count() == 16
            assert await page.locator("#health tbody tr").count() == 5
            assert await page.locator("#links tbody tr").count() == 2
            old_points = await page.get_attribute("#scan-trace", "points")
            old_x2 = float(await page.get_attribute("#bearing-line", "x2") or "nan")
            assert old_points and old_x2 < 0  # leader 20 deg to the left: line leans left

            # A new scan with the leader 60 deg to the right arrives.
            scan = synthetic_scan(clock.now(), -60.0, peak_dbm=-35.0)
            state.last_scan = scan
            state.scan_count += 1
            state.bearing_deg = scan.bearing_deg
            state.rssi_leader_dbm = scan.rssi_leader_dbm
            state.state = DriveState.LEADER_LOST
            state.reason = "leader lost: widening scan"
            state.touch()

            await page.wait_for_function(
                "(old) => document.getElementById('scan-trace').getAttribute('points') !== old",
                arg=old_points, timeout=10_000)
            await page.wait_for_function(
                "document.getElementById('drive-state').textContent === 'leader_lost'", timeout=10_000)
            new_x2 = float(await page.get_attribute("#bearing-line", "x2") or "nan")
            assert new_x2 > 0  # now leans right
            assert await page.text_content("#reason") == "leader lost: widening scan"
            assert "state-leader_lost" in (await page.get_attribute("#drive-state", "class") or "")
            await page.screenshot(path=str(tmp_path / "live.png"), full_page=True)
        finally:
            await browser.close()

    assert not problems, problems
    # Offline: every request went to the robot itself (data: URLs need no network).
    foreign: list[Any] = [r for r in requests if not r.startswith(url) and not r.startswith("data:")]
    assert not foreign, foreign
