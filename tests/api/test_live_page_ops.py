"""The live page as an operator uses it, in a real headless Chromium.

- A `relayd run` subprocess on a FakeRig is paused (SIGSTOP), resumed and killed
  (SIGKILL) under an open page: within about 2 s the page greys out, says how old its
  data is, shows no state, wheel speed or device as current, and recovers by itself.
- An in-process daemon is stopped and driven from the page's buttons: the token is
  typed once (kept across a reload of the tab), HOLD needs no confirmation, follow
  does, 401 and network errors are shown. Reasons read in plain language, exactly as
  relayd.api.reasons writes them; sonar labels appear only where something echoes;
  the 5-minute history and the path trail come from the daemon and survive a reload;
  no grid row has an empty cell and the pose line never wraps, at three widths.
Screenshots go to the test's tmp_path (the stale page, the controls, three layouts).
"""

from __future__ import annotations

import asyncio
import signal
import socket
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from relayd.api.reasons import describe
from relayd.config.load import parse_settings
from relayd.daemon import Daemon
from relayd.fakes.rig import FakeRig
from tests.support import running, until
from tests.system.test_live_page_browser import CHROMIUM, CHROMIUM_ARGS, _require_chromium
from tests.tools.test_run_cli import Relayd

pytestmark = pytest.mark.browser

#: The page's promise is 2 s; allow the heartbeat (1 s), its 250 ms check and a loaded machine.
STALE_LIMIT_S = 6.0
SCAN = {"samples": 9, "width_deg": 120, "settle_s": 0.02}
PANTILT = {"speed_deg_s": 1000}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def wait_http(url: str, timeout_s: float = 30.0) -> dict[str, Any]:
    """The JSON document at `url` once it answers 200 (a daemon that is still starting)."""
    async with aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=2)) as session:

        async def answer() -> dict[str, Any] | None:
            try:
                async with session.get(url) as resp:
                    if resp.status == 200:
                        doc: dict[str, Any] = await resp.json()
                        return doc
            except (aiohttp.ClientError, TimeoutError, OSError):
                pass
            return None

        doc: dict[str, Any] = await until(
            answer, f"{url} to answer", timeout_s=timeout_s, poll_s=0.1
        )
        return doc


async def _browser(pw: Any) -> Any:
    return await pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)


def _watch(page: Any, problems: list[str]) -> None:
    page.on("console", lambda m: problems.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: problems.append(str(e)))


async def _is_stale(page: Any) -> bool:
    return bool(await page.evaluate("() => document.body.classList.contains('stale')"))


async def test_stale_when_the_daemon_is_paused_or_killed(tmp_path: Path) -> None:
    _require_chromium()
    from playwright.async_api import async_playwright

    port = free_port()
    url = f"http://127.0.0.1:{port}"
    async with FakeRig(tmp_path) as rig:
        config = rig.write_config(
            secrets_in_files=True,
            api_port=port,
            scan=SCAN,
            pantilt=PANTILT,
            control={"mode": "hold"},
            log={"format": "json"},
        )
        relayd = await Relayd.start("run", "-c", str(config))
        problems: list[str] = []
        try:
            await wait_http(url + "/status")
            async with async_playwright() as pw:
                browser = await _browser(pw)
                try:
                    page = await browser.new_page(viewport={"width": 1400, "height": 1000})
                    _watch(page, problems)
                    await page.goto(url + "/")
                    await page.wait_for_function(
                        "() => !document.body.classList.contains('stale')", timeout=20_000
                    )
                    await page.wait_for_function(
                        "() => document.getElementById('drive-state').textContent === 'stopped'",
                        timeout=20_000,
                    )
                    assert await page.text_content("#live-text") == "live"
                    assert not await page.is_visible("#stale-banner")
                    # Alive but (in hold) barely changing: heartbeats keep it current.
                    t_end = time.monotonic() + 3.0
                    while time.monotonic() < t_end:
                        assert not await _is_stale(page), "a live daemon's page went stale"
                        await asyncio.sleep(0.2)

                    # Paused: the connection stays open, nothing arrives.
                    relayd.proc.send_signal(signal.SIGSTOP)
                    t0 = time.monotonic()
                    await page.wait_for_function(
                        "() => document.body.classList.contains('stale')",
                        timeout=int(STALE_LIMIT_S * 1000),
                    )
                    went_stale_s = time.monotonic() - t0
                    assert went_stale_s < STALE_LIMIT_S
                    print(f"live page stale {went_stale_s:.2f} s after SIGSTOP")
                    assert await page.is_visible("#stale-banner")
                    assert await page.text_content("#drive-state") == "unknown"
                    assert await page.text_content("#mode") == "unknown"
                    assert await page.text_content("#wheel-l-val") == "—"
                    assert await page.text_content("#wheel-r-val") == "—"
                    assert "up" not in [
                        t.strip() for t in await page.locator("#health td").all_text_contents()
                    ]
                    assert (await page.text_content("#reason") or "").startswith(
                        "no current data \u00b7 last known: stopped: hold mode"
                    )
                    await page.wait_for_function(
                        "() => /last update [3-9] s ago/.test(document.getElementById('live-text').textContent)",
                        timeout=10_000,
                    )
                    # Ages keep growing from the last update: nothing says "0.0 s ago".
                    ages = [
                        float(t)
                        for t in await page.locator(
                            "#health tbody td:nth-child(3)"
                        ).all_text_contents()
                    ]
                    assert ages and min(ages) >= 2.0, ages
                    scan_age = float(
                        (await page.text_content("#scan-meta") or "").split(" · ")[1].split()[0]
                    )
                    assert scan_age >= 2.0
                    assert await page.text_content("#uptime") == "unknown"
                    opacity = await page.evaluate(
                        "() => getComputedStyle(document.querySelector('.motion-card')).opacity"
                    )
                    assert float(opacity) < 0.6
                    await page.screenshot(path=str(tmp_path / "stale-paused.png"), full_page=True)

                    # Resumed: live again without a reload.
                    relayd.proc.send_signal(signal.SIGCONT)
                    await page.wait_for_function(
                        "() => !document.body.classList.contains('stale')", timeout=20_000
                    )
                    await page.wait_for_function(
                        "() => document.getElementById('drive-state').textContent === 'stopped'",
                        timeout=10_000,
                    )
                    assert await page.text_content("#wheel-l-val") == "0 mm/s"

                    # Killed: stale at once (the stream breaks), and the page stays honest.
                    relayd.proc.kill()
                    await relayd.proc.wait()
                    t0 = time.monotonic()
                    await page.wait_for_function(
                        "() => document.body.classList.contains('stale')",
                        timeout=int(STALE_LIMIT_S * 1000),
                    )
                    killed_stale_s = time.monotonic() - t0
                    assert killed_stale_s < STALE_LIMIT_S
                    print(f"live page stale {killed_stale_s:.2f} s after SIGKILL")
                    assert await page.text_content("#drive-state") == "unknown"
                    assert await page.text_content("#wheel-l-val") == "—"
                    await page.wait_for_function(
                        "() => /last update [4-9] s ago/.test(document.getElementById('live-text').textContent)",
                        timeout=15_000,
                    )
                    assert await _is_stale(page)
                    # The stop button says plainly that nothing reached the robot.
                    await page.fill("#token-input", rig.api_token)
                    await page.click("#token-form button[type=submit]")
                    await page.click("#btn-hold")
                    await page.wait_for_function(
                        "() => /hold NOT confirmed .*(network error|no answer)/.test("
                        "document.getElementById('control-result').textContent)",
                        timeout=15_000,
                    )
                    await page.screenshot(path=str(tmp_path / "stale-killed.png"), full_page=True)
                finally:
                    await browser.close()
        finally:
            if relayd.proc.returncode is None:
                relayd.proc.send_signal(signal.SIGCONT)
            await relayd.kill()
    # Only the browser's own reports of the failed connections may appear.
    assert all(
        "ERR_CONNECTION_REFUSED" in p or "Failed to load resource" in p or "Failed to fetch" in p
        for p in problems
    ), problems


@pytest.fixture
async def served(tmp_path: Path) -> AsyncIterator[tuple[str, FakeRig, Daemon]]:
    _require_chromium()
    async with FakeRig(tmp_path, leader_xy_m=(6.0, 2.0)) as rig:
        daemon = Daemon(
            parse_settings(
                rig.config_doc(api_port=0, control={"mode": "hold"}, scan=SCAN, pantilt=PANTILT)
            ),
            env=rig.env,
        )
        async with running(daemon) as task:
            await until(lambda: daemon.api_port is not None or task.done(), "the API to bind", 20.0)
            if task.done():
                task.result()
            yield f"http://127.0.0.1:{daemon.api_port}", rig, daemon


#: Resolves once the browser has drawn two frames: any layout a change asked for is done.
NEXT_FRAME = "() => new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))"
LAYOUT_CHECK = """() => {
  const main = document.querySelector('main');
  const cs = getComputedStyle(main);
  const inner = main.clientWidth - parseFloat(cs.paddingLeft) - parseFloat(cs.paddingRight);
  const gap = parseFloat(cs.columnGap);
  const rows = new Map();
  for (const card of main.children) {
    const r = card.getBoundingClientRect();
    const key = Math.round(r.top);
    rows.set(key, (rows.get(key) || []).concat([r.width]));
  }
  const bad = [];
  for (const [top, widths] of rows) {
    const used = widths.reduce((a, b) => a + b, 0) + gap * (widths.length - 1);
    if (Math.abs(used - inner) > 2) bad.push(`row at ${top}: ${used.toFixed(0)} of ${inner.toFixed(0)} px`);
  }
  const pose = document.getElementById('pose');
  const lh = parseFloat(getComputedStyle(pose).lineHeight) || 22;
  if (pose.getBoundingClientRect().height > lh * 1.5) bad.push('pose wraps');
  const card = pose.closest('.card').getBoundingClientRect();
  if (pose.getBoundingClientRect().right > card.right + 1) bad.push('pose overflows its card');
  return bad;
}"""


async def test_controls_reasons_history_and_layout(
    served: tuple[str, FakeRig, Daemon], tmp_path: Path
) -> None:
    from playwright.async_api import async_playwright

    url, rig, daemon = served
    state = daemon.state
    problems: list[str] = []
    async with async_playwright() as pw:
        browser = await _browser(pw)
        try:
            page = await browser.new_page(viewport={"width": 1400, "height": 1000})
            _watch(page, problems)
            await page.goto(url + "/")
            await page.wait_for_function(
                "() => document.getElementById('reason-code').textContent === 'hold'",
                timeout=20_000,
            )
            assert (
                await page.text_content("#reason")
                == "stopped: hold mode (an operator asked it to stand still)"
            )

            # No token yet: a stop is still one click, and the robot accepts it ...
            await page.click("#btn-hold")
            await page.wait_for_function(
                "() => /hold: accepted by the robot/.test(document.getElementById('control-result').textContent)",
                timeout=10_000,
            )
            # ... while follow is not sent, and the page says why.
            await page.click("#btn-follow")
            await page.click("#confirm-yes")
            # Waited for: the hold's answer is still shown until the page has handled the
            # click (read at once, it was, on a loaded machine).
            await page.wait_for_function(
                "() => /enter the API token first/.test(document.getElementById('control-result').textContent)",
                timeout=10_000,
            )
            # A wrong token: the API's 401 is shown.
            await page.fill("#token-input", "not-the-token")
            await page.click("#token-form button[type=submit]")
            await page.click("#btn-follow")
            await page.click("#confirm-yes")
            await page.wait_for_function(
                "() => /HTTP 401 wrong bearer token/.test(document.getElementById('control-result').textContent)",
                timeout=10_000,
            )
            await page.click("#token-forget")
            assert await page.evaluate("() => sessionStorage.getItem('relayd-api-token')") is None
            await page.fill("#token-input", rig.api_token)
            await page.click("#token-form button[type=submit]")
            assert (
                await page.evaluate("() => sessionStorage.getItem('relayd-api-token')")
                == rig.api_token
            )

            # follow asks first; cancelling sends nothing: of the mode requests the page
            # makes, the one after the confirmation below is the first.
            mode_posts: list[str] = []
            page.on(
                "request",
                lambda r: (
                    mode_posts.append(r.post_data or "")
                    if r.method == "POST" and r.url.endswith("/api/mode")
                    else None
                ),
            )
            rig.set_rear_signal(-70.0)  # so that follow stops on the weak link behind
            await page.click("#btn-follow")
            assert await page.is_visible("#confirm")
            assert "drive by itself" in (await page.text_content("#confirm-text") or "")
            await page.click("#confirm-no")
            await page.wait_for_function(
                "() => /cancelled, nothing sent/.test(document.getElementById('control-result').textContent)",
                timeout=5_000,
            )
            assert str(state.mode) == "hold"
            await page.click("#btn-follow")
            await page.click("#confirm-yes")
            await page.wait_for_function(
                "() => /follow: accepted by the robot \\(HTTP 200/.test("
                "document.getElementById('control-result').textContent)",
                timeout=10_000,
            )
            await until(lambda: str(state.mode) == "follow", "follow mode")
            assert len(mode_posts) == 1 and "follow" in mode_posts[0], mode_posts

            # The weak link behind, in words and numbers, as the Python side writes it.
            await page.wait_for_function(
                "() => document.getElementById('reason-code').textContent === 'rear_weak'",
                timeout=60_000,
            )
            shown = await page.text_content("#reason")
            assert shown == describe(state.snapshot(daemon.clock.now()))
            assert shown == "stopped: the link behind is weak (\u221270 dBm \u2264 \u221260)"

            # HOLD: no dialog, straight to the robot.
            await page.click("#btn-hold")
            await page.wait_for_function(
                "() => /hold: accepted/.test(document.getElementById('control-result').textContent)",
                timeout=10_000,
            )
            assert not await page.is_visible("#confirm")
            await until(lambda: str(state.mode) == "hold", "hold mode")

            # Sonar: one echo, one label; the rest saw nothing and carry no number.
            rig.robot.sonar_fn = lambda x, y, th: [None, None, None, 1200.0] + [None] * 12
            await page.wait_for_function(
                "() => document.querySelectorAll('#sonar-rays .range-label').length === 1",
                timeout=10_000,
            )
            assert await page.text_content("#sonar-rays .range-label") == "1.20"
            assert await page.text_content("#sonar-min") == "front min 1.20 m"
            assert await page.locator("#sonar-rays line").count() == 16

            # History: drawn from the daemon, with both threshold lines, and a path trail.
            await page.wait_for_function(
                "() => parseInt(document.getElementById('hist-count').textContent) >= 6",
                timeout=30_000,
            )
            assert await page.locator("#hist-rssi line.thr").count() == 2
            assert (await page.get_attribute("#hist-rb", "d") or "").startswith("M")
            assert (await page.get_attribute("#hist-rl", "d") or "").startswith("M")
            assert await page.locator("#hist-state rect.band-stopped").count() >= 1
            assert len((await page.get_attribute("#trail", "points") or "").split()) >= 2
            # Manual (confirmed from the page), then drive straight ahead for a few seconds
            # through the API: the trail follows the odometry forward (screen y = -x in m).
            await page.click("#btn-manual")
            assert "MANUAL" in (await page.text_content("#confirm-text") or "")
            await page.click("#confirm-yes")
            await until(lambda: str(state.mode) == "manual", "manual mode")
            async with aiohttp.ClientSession(
                headers={"Authorization": f"Bearer {rig.api_token}"}
            ) as http:
                # Until the robot is 0.8 m ahead (about 3 s idle; a loaded machine's late
                # requests let the deadman stop it between them, so no fixed time suffices).
                t_end = time.monotonic() + 30.0
                while (state.x_mm or 0.0) <= 800.0 and time.monotonic() < t_end:
                    async with http.post(
                        url + "/api/drive", json={"left_mm_s": 400.0, "right_mm_s": 400.0}
                    ) as r:
                        assert r.status == 200, await r.text()
                    await asyncio.sleep(0.15)
            assert (state.x_mm or 0.0) > 800.0
            await page.wait_for_function(
                "() => document.getElementById('trail').getAttribute('points').split(' ')"
                ".some(p => parseFloat(p.split(',')[1]) < -0.8)",
                timeout=15_000,
            )
            assert "m in the last 5 min" in (await page.text_content("#path-meta") or "")
            before = int((await page.text_content("#hist-count") or "0").split()[0])
            await page.screenshot(path=str(tmp_path / "controls.png"), full_page=True)

            # A reload keeps the history (it lives in the daemon) and the token (this tab).
            await page.reload()
            await page.wait_for_function(
                "(n) => parseInt(document.getElementById('hist-count').textContent) >= n",
                arg=before,
                timeout=10_000,
            )
            assert not await page.is_visible("#token-form")
            await page.click("#btn-hold")
            await page.wait_for_function(
                "() => /hold: accepted/.test(document.getElementById('control-result').textContent)",
                timeout=10_000,
            )

            for width in (1400, 1000, 700):
                await page.set_viewport_size({"width": width, "height": 1000})
                await page.evaluate(NEXT_FRAME)  # the page laid out again at the new width
                assert await page.evaluate(LAYOUT_CHECK) == [], f"layout at {width} px"
                await page.screenshot(path=str(tmp_path / f"layout-{width}.png"), full_page=True)
        finally:
            await browser.close()
    # The deliberate wrong token is the one error the browser may report.
    assert [p for p in problems if "status of 401" not in p] == [], problems
