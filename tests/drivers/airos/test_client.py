"""AirOsClient and AirOsPoller against FakeAirOs over loopback HTTP(S): the real login flows,
unit-true live values, and every failure switch with the poller's recovery policy."""

from __future__ import annotations

import asyncio
import ssl
import warnings
from pathlib import Path

import aiohttp
import pytest
from pydantic import SecretStr
from structlog.testing import capture_logs

from drivers.airos import (
    AirOsAuthError,
    AirOsClient,
    AirOsConnectionError,
    AirOsPoller,
    AirOsSessionExpired,
    LinkQuality,
    Station,
    legacy_tls_context,
)
from drivers.airos.fake import FakeAirOs
from drivers.transport.clock import Clock
from tests.support import LoopClock, until

pytestmark = pytest.mark.virtual_time

FIXTURES = Path(__file__).parents[2] / "fixtures" / "airos"
LOCO_AP = FIXTURES / "status_cgi_NanoStation_loco_M5_XM_v6.3.16_ap.json"
XW_STA = FIXTURES / "status_cgi_NanoStation_M5_XW_v6.3.16_sta.json"
SECRET = "Pa55-w0rd-XYZZY"

# A throwaway self-signed certificate for 127.0.0.1, like the radios' own.
CERT_PEM = """\
-----BEGIN CERTIFICATE-----
MIIDCzCCAfOgAwIBAgIUOVbs/ytSekCyd2NoUXtDuqYGMegwDQYJKoZIhvcNAQEL
BQAwFDESMBAGA1UEAwwJMTI3LjAuMC4xMCAXDTI2MTEyMzE5MzQ0M1oYDzIxMjYx
MDMwMTkzNDQzWjAUMRIwEAYDVQQDDAkxMjcuMC4wLjEwggEiMA0GCSqGSIb3DQEB
AQUAA4IBDwAwggEKAoIBAQCHYhhiY5IRzBzwnjdWqJy47DtVz4VdiEs/3QAD1HkO
gnFcZ7+RAtYTHTWA9BFO6KVDFdQsy7rVUG/YjIQC6EqiIPj/1H7XXCgV1G6Rl3Au
Vsoxia4sM1XFgAlf5lzU0I55bWOBAcvrmfXZUnh+ZQCpjZRZaMLBapz5TpSh95Aa
PfcvlMwekAp/91LifRgzWn+rfjk5mA6UgA6v0rLlGOgGYdfjgkPtc05CU5YRZVl8
qNjI9MiDgNvk1i/fTLbZgoxuVAXVAGhWkFhv0UHNVcMi2wX/Vo2wQmWlwlSXMnW3
5lhg/ORKzTtfiHoVYUhc3mIiH7hHXc95D8iZ4rOlFpGXAgMBAAGjUzBRMB0GA1Ud
DgQWBBTqma4e1Yv8DBfabw4hd6BarmOJcDAfBgNVHSMEGDAWgBTqma4e1Yv8DBfa
bw4hd6BarmOJcDAPBgNVHRMBAf8EBTADAQH/MA0GCSqGSIb3DQEBCwUAA4IBAQA0
tAqwnEZvwWWt4bybFSsLoTIkPFwePEEJUDLHchXnMWvd2ESGJA1GNIH4VnjdryKL
1DZDB1rpO1R7nMug5kwhfTktvoen+EMOCXJWdCemPKItIdWFQBd3nmBH4WI6tuYb
ToXzlVByovdAd2Gdf88zGFGlbq2IooW7rzkcEMLA8ooBY9rqLrpv1w35F7TMcR3w
B+kzuJUVUHQ9RLSeB7t/bW86Aw0Andsfb1jIsqXhSiTXsbrO/7wmvDG+V/ftHbBM
ZwP3YDLaA3d21KXXCiMjotMd57rVfLJAXsK87LvauQAFEmJYTW+sUZZ0hT05CXkO
MZqWCJVkZHyottYgZgOn
-----END CERTIFICATE-----
"""

KEY_PEM = """\
-----BEGIN PRIVATE KEY-----
MIIEvgIBADANBgkqhkiG9w0BAQEFAASCBKgwggSkAgEAAoIBAQCHYhhiY5IRzBzw
njdWqJy47DtVz4VdiEs/3QAD1HkOgnFcZ7+RAtYTHTWA9BFO6KVDFdQsy7rVUG/Y
jIQC6EqiIPj/1H7XXCgV1G6Rl3AuVsoxia4sM1XFgAlf5lzU0I55bWOBAcvrmfXZ
Unh+ZQCpjZRZaMLBapz5TpSh95AaPfcvlMwekAp/91LifRgzWn+rfjk5mA6UgA6v
0rLlGOgGYdfjgkPtc05CU5YRZVl8qNjI9MiDgNvk1i/fTLbZgoxuVAXVAGhWkFhv
0UHNVcMi2wX/Vo2wQmWlwlSXMnW35lhg/ORKzTtfiHoVYUhc3mIiH7hHXc95D8iZ
4rOlFpGXAgMBAAECggEALNNmloE4dqsaM/N3CDr49WPGe7GkC2Wa4NDoddwunwbC
ySFS9Q0224pS0lk9t95hBdbe81wbhxDEj7Nq7FmEiK0ZNP/jZaROY3f8ijlVvAoh
lYhsQpdWwXeU4wtv1kkdu4fkJ+1z2xUVqXjci6EeuIU3xujgf1ExG30QypYhQQaj
Ht0UNLQJ3s1eeBHxKP+YmUpl+b9UVv5dWqqKry5aAELfTS2BVWcGcRVb9zXzBeA6
vnzzFzEUx/RWsmJohV+ONvH57tJ8dnF2fy+NstKCN7JtLria7hO8q2DGdz19f8+x
sx5VxUtsWGnY7a6nLrQf8+lt72DpOAZGAlxIIOPA8QKBgQC6T7BL8OEo0+7OiH5S
NS0h38QuG/mti1sLahO1pbKTSmvESx/wrWeI2O1Ds3EppZ33fE/BEmeYcEBeYIVD
f1FdoJfIGw1CmOoeukGZAvMp7AzdpgiwJsi2vPZA5u5wju4PllBATB5s+V38iEEY
kQdjTz8fKgF7q8UBJV4C2N/XMQKBgQC6BcQgpRIuJrZ0zBiJVK9wS665+gQepbf7
ZbHm1GtlWAIjhXOMpuwCGMilwcGAhPJSeGY5X4Gu/UCFRNceaa/vJ/XckIGQRexW
ti4Q2hjUBbDKBSexWOiu3eEVjuon3WADh97eqxDS/YCLFqwBpuj2DslV0W2FZLye
Z3YAus1TRwKBgQCRRaOkgy09pYr2dc1xkk8fs5gHj/6uCBQ0oUC/CXVljcjb5OwB
wWQSe3r9qARbweybVc3mMNCgNx6puD8Q80xhYeAXwqgjPpKG5RpTEc7C6HDbvyPV
HliwzESDNM3E7F3Jv53RlMjAlexoBWIkoqkNEXSZeypu4O+axiU4uRxIcQKBgQC0
7izPz546Mz8dpPFsiWjGIWaFzu443Nhw9X2uVQdMH+icog08TZKZi3+E8UqC9Uw3
+JD81q7tA7fAp69QDl2nkEdrS0YpjEkOIc32aBrkBdDo/VCZBy/x/S8S59lKAuCD
LqEQFHSdsyFWpyuPw8cspD8hcDxFFTD8JQc6OHbCuwKBgBkxvPc9DFSPgf2TsfYa
oLTYrYI2Fl10mHA9H8m7fr3wrWUZErtJWzmz9sCi0NbTApSvv8Vd9gj0CYG5rHED
w1nMTDVGeBXH05TZBWKk4QkI+sFLTisWSx/i/g5HRkJAm0xcvW/BlwfTqz+GnyDz
+tWXNWvBt0vzwZyN7XMSJhFv
-----END PRIVATE KEY-----
"""


@pytest.fixture
async def fake6():
    async with FakeAirOs("ubnt", SECRET) as fake:
        yield fake


@pytest.fixture
async def fake8():
    async with FakeAirOs("ubnt", SECRET, version=8) as fake:
        yield fake


# -- client ----------------------------------------------------------------------------------


async def test_v6_cookie_login_and_status(fake6: FakeAirOs) -> None:
    client = AirOsClient(fake6.base_url or "", "ubnt", SECRET)
    try:
        q = await client.fetch()
        assert client.firmware == 6 and client.logged_in
        assert (q.signal_dbm, q.rssi, q.noise_dbm, q.ccq_pct, q.tx_mbps, q.rx_mbps) == (
            -46,
            50,
            -89,
            73.8,
            243,
            180,
        )
        assert q.mode == "sta" and q.hostname == "NanoStation loco M5 Client"
        assert fake6.login_content_types == ["multipart/form-data"]
        await client.fetch()
        assert fake6.counters["logins"] == 1 and fake6.counters["status"] == 2  # session reused
    finally:
        await client.close()
    assert fake6.counters["logouts"] == 1


async def test_v6_not_logged_in_is_redirected_to_login(fake6: FakeAirOs) -> None:
    async with (
        aiohttp.ClientSession() as http,
        http.get(f"{fake6.base_url}/status.cgi", allow_redirects=False) as resp,
    ):
        assert resp.status == 302
        assert resp.headers["Location"] == "/login.cgi?uri=/status.cgi"
        assert any(name.startswith("AIROS_") for name in resp.cookies)


async def test_v8_api_auth_with_csrf_header(fake8: FakeAirOs) -> None:
    client = AirOsClient(fake8.base_url or "", "ubnt", SECRET)
    try:
        q = await client.fetch()
        assert client.firmware == 8
        assert q.signal_dbm == -46
        assert fake8.login_content_types == []  # no v6 form was posted
    finally:
        await client.close()
    # The session cookie alone is not enough on airOS 8: X-CSRF-ID must come with it.
    async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as http:
        async with http.post(
            f"{fake8.base_url}/api/auth", json={"username": "ubnt", "password": SECRET}
        ) as resp:
            assert resp.status == 200
            csrf = resp.headers["X-CSRF-ID"]
        async with http.get(f"{fake8.base_url}/status.cgi") as resp:
            assert resp.status == 401
        async with http.get(f"{fake8.base_url}/status.cgi", headers={"X-CSRF-ID": csrf}) as resp:
            assert resp.status == 200
            assert (await resp.json())["wireless"]["signal"] == -46


@pytest.mark.parametrize("version", [6, 8])
async def test_wrong_password_is_an_auth_error(version: int) -> None:
    async with FakeAirOs("ubnt", "right-one", version=version) as fake:
        client = AirOsClient(fake.base_url or "", "ubnt", SECRET)
        with pytest.raises(AirOsAuthError) as info:
            await client.login()
        await client.close()
        assert fake.counters["failed_logins"] == 1
        text = f"{info.value} {info.value!r} {info.value.args}"
        assert SECRET not in text and "ubnt" in text


@pytest.mark.parametrize("api_auth_status", [404, 403, 302])
async def test_auto_firmware_falls_back_to_the_v6_form(api_auth_status: int) -> None:
    async with FakeAirOs("ubnt", SECRET) as fake:
        fake.v6_api_auth_status = api_auth_status
        client = AirOsClient(fake.base_url or "", "ubnt", SECRET)
        try:
            assert (await client.fetch()).signal_dbm == -46
            assert client.firmware == 6 and fake.counters["logins"] == 1
        finally:
            await client.close()


async def test_expired_session_is_detected(fake6: FakeAirOs) -> None:
    client = AirOsClient(fake6.base_url or "", "ubnt", SECRET)
    try:
        await client.fetch()
        fake6.expire_sessions()
        with pytest.raises(AirOsSessionExpired, match=r"login\.cgi"):
            await client.fetch()
        assert not client.logged_in
        assert (await client.fetch()).signal_dbm == -46  # fetch() logs in again by itself
        assert fake6.counters["logins"] == 2
    finally:
        await client.close()


async def test_ap_station_list_from_sta_cgi() -> None:
    async with FakeAirOs("ubnt", SECRET, fixture=LOCO_AP) as fake:
        client = AirOsClient(fake.base_url or "", "ubnt", SECRET)
        try:
            q = await client.fetch()
            # Without set_stations the fake mirrors its link as the single station.
            assert [s.signal_dbm for s in q.stations] == [-45]
            assert q.stations[0].ccq_pct == 87.0  # sta.cgi percent, from status.cgi's 870 per-mille
            fake.set_stations(
                [
                    Station(
                        mac="00:27:22:AA:BB:01", signal_dbm=-71, ccq_pct=64, tx_mbps=52, rx_mbps=39
                    ),
                    Station(
                        mac="00:27:22:AA:BB:02",
                        signal_dbm=-58.4,
                        ccq_pct=93.5,
                        tx_mbps=130.0,
                        rx_mbps=117.0,
                    ),
                ]
            )
            q = await client.fetch()
            assert q.mode == "ap" and q.signal_dbm == -45
            assert [(s.mac, s.signal_dbm, s.ccq_pct) for s in q.stations] == [
                ("00:27:22:AA:BB:01", -71, 64),
                ("00:27:22:AA:BB:02", -58, 94),
            ]
            assert q.best_station_signal_dbm == -58
            assert q.station_signal_dbm("00:27:22:aa:bb:01") == -71
            assert fake.counters["sta"] == 2
        finally:
            await client.close()


async def test_set_link_is_served_in_the_radios_units(fake6: FakeAirOs) -> None:
    fake6.set_link(-63.4, noise_dbm=-97, ccq_pct=81.2, tx_mbps=144.4, rx_mbps=65)
    w = fake6.status_doc["wireless"]
    assert (w["signal"], w["rssi"], w["noisef"], w["ccq"], w["txrate"], w["rxrate"]) == (
        -63,
        33,
        -97,
        812,
        "144.4",
        "65",
    )
    client = AirOsClient(fake6.base_url or "", "ubnt", SECRET)
    try:
        q = await client.fetch()
    finally:
        await client.close()
    assert (q.signal_dbm, q.rssi, q.noise_dbm, q.ccq_pct, q.tx_mbps, q.rx_mbps) == (
        -63,
        33,
        -97,
        81.2,
        144.4,
        65,
    )


async def test_fixture_file_is_served(tmp_path: Path) -> None:
    async with FakeAirOs("ubnt", SECRET, fixture=XW_STA) as fake:
        client = AirOsClient(fake.base_url or "", "ubnt", SECRET, firmware=6)
        try:
            q = await client.fetch()
        finally:
            await client.close()
        assert (q.signal_dbm, q.ccq_pct, q.essid) == (-64, 99.1, "Nano")
    bad = tmp_path / "x.json"
    bad.write_text('{"host": {}}')
    with pytest.raises(ValueError, match="wireless"):
        FakeAirOs(fixture=bad)


async def test_bad_url_and_password_types() -> None:
    with pytest.raises(ValueError):
        AirOsClient("ftp://192.168.1.20", "ubnt", SECRET)
    client = AirOsClient("http://192.168.1.20", "ubnt", SecretStr(SECRET))
    assert SECRET not in repr(client) and SECRET not in str(vars(client))


# -- TLS -------------------------------------------------------------------------------------


def test_legacy_tls_context_settings() -> None:
    ctx = legacy_tls_context()
    assert ctx.minimum_version == ssl.TLSVersion.TLSv1
    assert ctx.verify_mode == ssl.CERT_NONE and not ctx.check_hostname
    assert ctx.options & getattr(ssl, "OP_LEGACY_SERVER_CONNECT", 0) == getattr(
        ssl, "OP_LEGACY_SERVER_CONNECT", 0
    )
    https = AirOsClient("https://10.0.0.1", "ubnt", SECRET, legacy_tls=True)
    assert (
        https.ssl_context is not None and https.ssl_context.minimum_version == ssl.TLSVersion.TLSv1
    )
    modern = AirOsClient("https://10.0.0.1", "ubnt", SECRET)
    assert (
        modern.ssl_context is not None
        and modern.ssl_context.minimum_version != ssl.TLSVersion.TLSv1
    )
    assert AirOsClient("http://10.0.0.1", "ubnt", SECRET).ssl_context is None


def _tls10_server_context(tmp_path: Path) -> ssl.SSLContext:
    """What airOS 6's lighttpd offers: TLS 1.0 only, legacy security level."""
    (tmp_path / "cert.pem").write_text(CERT_PEM)
    (tmp_path / "key.pem").write_text(KEY_PEM)
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.load_cert_chain(tmp_path / "cert.pem", tmp_path / "key.pem")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        ctx.minimum_version = ssl.TLSVersion.TLSv1
        ctx.maximum_version = ssl.TLSVersion.TLSv1
    ctx.set_ciphers("DEFAULT:@SECLEVEL=0")
    return ctx


async def test_legacy_tls_talks_to_a_tls10_only_radio(tmp_path: Path) -> None:
    async with FakeAirOs("ubnt", SECRET, ssl_context=_tls10_server_context(tmp_path)) as fake:
        url = fake.base_url or ""
        assert url.startswith("https://")
        modern = AirOsClient(url, "ubnt", SECRET, timeout_s=2)
        with pytest.raises(AirOsConnectionError):  # OpenSSL 3 at SECLEVEL 2 refuses TLS 1.0
            await modern.fetch()
        await modern.close()
        legacy = AirOsClient(url, "ubnt", SECRET, legacy_tls=True, timeout_s=2)
        try:
            assert (await legacy.fetch()).signal_dbm == -46  # self-signed cert accepted too
        finally:
            await legacy.close()


# -- poller ----------------------------------------------------------------------------------


def _poller(
    fake: FakeAirOs, clock: Clock, password: str = SECRET, timeout_s: float = 5.0, **kw
) -> AirOsPoller:
    # timeout_s is clock time: 5 s at speed 20 is 250 ms of wall time, ample on loopback.
    return AirOsPoller(
        fake.base_url or "", "ubnt", password, poll_s=1.0, timeout_s=timeout_s, clock=clock, **kw
    )


async def _stop(task: asyncio.Task) -> None:
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


async def test_poller_polls_at_the_clock_rate_and_logs_out_on_cancel() -> None:
    clock = LoopClock()
    updates: list[LinkQuality] = []
    async with FakeAirOs("ubnt", SECRET, clock=clock) as fake:
        poller = _poller(fake, clock, on_update=updates.append)
        assert poller.state == "connecting" and poller.latest is None and poller.age_s() is None
        task = asyncio.create_task(poller.run())
        await until(lambda: poller.counters["polls"] >= 4)
        t0 = clock.now()
        await until(lambda: poller.counters["polls"] >= 8)
        assert 3.0 <= clock.now() - t0 <= 8.0  # ~1 poll per clock second (slack for a busy CI box)
        assert poller.state == "ok" and poller.last_error is None
        assert poller.latest is updates[-1] and poller.latest.signal_dbm == -46
        assert poller.last_update_t == poller.latest.t and poller.is_fresh(2.0)
        assert poller.counters["logins"] == 1 and poller.counters["errors"] == 0
        fake.set_link(-70)
        await until(lambda: poller.latest is not None and poller.latest.signal_dbm == -70)
        await _stop(task)
        assert fake.counters["logouts"] == 1


async def test_poller_relogs_in_after_session_expiry() -> None:
    clock = LoopClock()
    async with FakeAirOs("ubnt", SECRET, clock=clock) as fake:
        poller = _poller(fake, clock)
        task = asyncio.create_task(poller.run())
        await until(lambda: poller.counters["polls"] >= 2)
        fake.expire_sessions()
        polls = poller.counters["polls"]
        await until(lambda: poller.counters["polls"] >= polls + 2)
        assert poller.counters["relogins"] == 1 and poller.counters["logins"] == 2
        assert poller.counters["errors"] == 0 and poller.state == "ok"
        assert fake.counters["redirects"] == 1
        await _stop(task)


async def test_poller_counts_timeouts_then_recovers() -> None:
    clock = LoopClock()
    async with FakeAirOs("ubnt", SECRET, clock=clock) as fake:
        poller = _poller(fake, clock, timeout_s=2.0)
        task = asyncio.create_task(poller.run())
        await until(lambda: poller.state == "ok")
        fake.slow_s = 6.0  # clock seconds, beyond timeout_s=2
        await until(lambda: poller.counters["timeouts"] >= 2)
        assert poller.state == "unreachable" and "no answer within 2 s" in (poller.last_error or "")
        assert not poller.is_fresh(1.0)
        fake.slow_s = 0.0
        await until(lambda: poller.state == "ok")
        assert poller.last_error is None
        await _stop(task)


async def test_poller_counts_malformed_json_then_recovers() -> None:
    clock = LoopClock()
    async with FakeAirOs("ubnt", SECRET, clock=clock) as fake:
        poller = _poller(fake, clock)
        task = asyncio.create_task(poller.run())
        await until(lambda: poller.state == "ok")
        good = poller.latest
        fake.malformed = True
        await until(lambda: poller.counters["bad_json"] >= 2)
        assert poller.state == "bad_data" and "malformed JSON" in (poller.last_error or "")
        assert poller.latest is good  # bad data never replaces the last good reading
        fake.malformed = False
        await until(lambda: poller.state == "ok")
        assert poller.latest is not good
        await _stop(task)


async def test_poller_wrong_password_retries_on_the_capped_backoff_and_logs_once_a_minute() -> None:
    clock = LoopClock()
    with capture_logs() as logs:
        async with FakeAirOs("ubnt", "the-real-one", clock=clock) as fake:
            poller = _poller(fake, clock, timeout_s=20.0)
            task = asyncio.create_task(poller.run())
            await until(lambda: poller.state == "auth_failed")
            t0 = clock.now()
            assert "login refused" in (poller.last_error or "")
            await clock.sleep(130.0 - (clock.now() - t0))
            tries = fake.counters["failed_logins"]
            # Backoff 1, 2, 4, then every 5 s (the cap, max(5 s, 4 polls)): no retry storm,
            # and no 60 s wait either.
            assert 20 <= tries <= 30, tries
            assert poller.state == "auth_failed" and poller.counters["polls"] == 0
            assert poller.counters["auth_failures"] == tries and fake.counters["status"] == 0
            await _stop(task)
    loud = [e for e in logs if e["event"] == "airos_auth_failed" and e["log_level"] != "debug"]
    # The first refusal, then a reminder once a minute (at ~60 and ~120 s).
    assert 2 <= len(loud) <= 3, [(e["log_level"], e["attempt"]) for e in loud]


async def test_poller_picks_up_a_fixed_password_within_the_backoff_cap() -> None:
    """The radio's password was changed, then changed back while polling (a refused
    login once held the robot for up to 60 s)."""
    clock = LoopClock()
    async with FakeAirOs("ubnt", SECRET, clock=clock) as fake:
        poller = _poller(fake, clock)
        task = asyncio.create_task(poller.run())
        await until(lambda: poller.state == "ok")
        fake.set_password("changed-on-the-radio")
        fake.expire_sessions()
        await until(lambda: poller.state == "auth_failed")
        await until(lambda: fake.counters["failed_logins"] >= 4, "four refused logins")
        fake.set_password(SECRET)
        t_fixed = clock.now()
        await until(lambda: poller.state == "ok", timeout_s=10)
        # At most one backoff cap (max(5 s, 4 polls) = 5 s), plus a request's time.
        assert clock.now() - t_fixed <= 6.0, clock.now() - t_fixed
        assert poller.last_error is None
        await _stop(task)


async def test_poller_backs_off_while_down_then_recovers() -> None:
    clock = LoopClock()
    async with FakeAirOs("ubnt", SECRET, clock=clock) as fake:
        poller = _poller(fake, clock)
        task = asyncio.create_task(poller.run())
        await until(lambda: poller.state == "ok")
        await fake.set_down(True)
        await until(lambda: poller.state == "unreachable")
        t0, errors0 = clock.now(), poller.counters["errors"]
        await asyncio.sleep(clock.to_real(14.0))
        # Backoff 1, 2, 4, 8 clock s: a handful of attempts in 14 s, not one per poll_s.
        attempts = poller.counters["errors"] - errors0
        assert 2 <= attempts <= 5, (attempts, clock.now() - t0)
        await fake.set_down(False)
        await until(lambda: poller.state == "ok", timeout_s=10)
        assert poller.counters["relogins"] == 0  # the radio kept the session
        await _stop(task)


async def test_poller_notices_a_radio_back_within_seconds_after_a_long_outage() -> None:
    # The relay may be held still while RSSI^b is unknown: after minutes of outage the
    # backoff must still be short enough to see the radio back within a few seconds.
    clock = LoopClock()
    async with FakeAirOs("ubnt", SECRET, clock=clock) as fake:
        poller = _poller(fake, clock)
        task = asyncio.create_task(poller.run())
        await until(lambda: poller.state == "ok")
        await fake.set_down(True)
        await asyncio.sleep(clock.to_real(100.0))
        assert poller.state == "unreachable"
        await fake.set_down(False)
        t_back = clock.now()
        await until(lambda: poller.state == "ok", timeout_s=10)
        assert clock.now() - t_back <= 6.0, clock.now() - t_back
        await _stop(task)


async def test_poller_survives_a_failing_callback(fake6: FakeAirOs) -> None:
    clock = LoopClock()

    def boom(q: LinkQuality) -> None:
        raise RuntimeError("consumer bug")

    poller = _poller(fake6, clock, on_update=boom)
    task = asyncio.create_task(poller.run())
    await until(lambda: poller.counters["polls"] >= 3)
    assert poller.counters["callback_errors"] >= 3 and poller.state == "ok"
    await _stop(task)


async def test_password_never_appears_anywhere() -> None:
    clock = LoopClock()
    with capture_logs() as logs:
        async with FakeAirOs("ubnt", "another-secret", clock=clock) as wrong:
            bad = _poller(wrong, clock)
            task = asyncio.create_task(bad.run())
            await until(lambda: bad.counters["auth_failures"] >= 2)
            texts = [repr(bad), repr(bad.client), str(bad.last_error), str(vars(bad.client))]
            await _stop(task)
        async with FakeAirOs("ubnt", SECRET, clock=clock) as fake:
            good = _poller(fake, clock)
            task = asyncio.create_task(good.run())
            await until(lambda: good.state == "ok")
            fake.expire_sessions()
            fake.malformed = True
            await until(lambda: good.counters["bad_json"] >= 1)
            fake.malformed = False
            await until(lambda: good.state == "ok")
            texts += [repr(good), str(good.counters), repr(good.latest)]
            await _stop(task)
    assert any(e["event"] == "airos_auth_failed" for e in logs)
    assert any(e["event"] == "airos_session_expired" for e in logs)
    texts += [repr(e) for e in logs]
    leaks = [t for t in texts if SECRET in t]
    assert not leaks
    assert "**" in repr(SecretStr(SECRET))


async def test_poller_backs_off_when_a_fresh_session_is_refused_at_once() -> None:
    clock = LoopClock()
    async with FakeAirOs("ubnt", SECRET, clock=clock) as fake:
        # A radio that accepts the login but then sends every status request back to the
        # login page (e.g. a firmware that wants another header): no tight login loop.
        fake._authorised = lambda request: False  # type: ignore[method-assign]
        poller = _poller(fake, clock)
        task = asyncio.create_task(poller.run())
        await until(lambda: poller.state == "bad_data")
        assert "refused right after login" in (poller.last_error or "")
        logins0 = fake.counters["logins"]
        await asyncio.sleep(clock.to_real(14.0))
        assert fake.counters["logins"] - logins0 <= 5  # backoff 1, 2, 4, 8 s
        assert poller.counters["polls"] == 0 and poller.latest is None
        await _stop(task)
