"""RSSI sources: procfs against the ProcfsWriter fake, iw against a fake `iw` binary,
nl80211 with pyroute2 messages and a stand-in socket, freshness, rejection, vanishing."""

from __future__ import annotations

import asyncio
import errno
import itertools
import os
import stat
import threading
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from pyroute2.netlink.exceptions import NetlinkError
from pyroute2.netlink.nl80211 import NL80211_NAMES, nl80211cmd

from drivers.wifi import (
    IwSource,
    Nl80211Source,
    ProcfsSource,
    ProcfsWriter,
    RssiSample,
    make_source,
)
from drivers.wifi.fake import format_proc_row
from drivers.wifi.nl80211 import observe_stations, station_reading
from drivers.wifi.parsers import PROC_HEADER_1, PROC_HEADER_2, parse_proc_net_wireless
from tests.support import LoopClock

FIXTURES = Path(__file__).parents[2] / "fixtures" / "wifi"


# ------------------------------------------------------------------------ ProcfsWriter


def test_writer_file_has_kernel_headers_and_one_update_per_write(tmp_path: Path) -> None:
    path = tmp_path / "wireless"
    w = ProcfsWriter(path, "wlan1")
    w.write(-60)
    lines = path.read_text().splitlines()
    assert lines[:2] == [PROC_HEADER_1, PROC_HEADER_2]
    assert lines[2] == format_proc_row(
        "wlan1",
        link=50,
        link_updated=True,
        level=-60,
        level_updated=True,
        noise=-95,
        noise_updated=True,
        misc=1,
    ).rstrip("\n")
    first = parse_proc_net_wireless(path.read_text())["wlan1"]
    w.write(-60)
    second = parse_proc_net_wireless(path.read_text())["wlan1"]
    assert (first.level, second.level) == (-60, -60)
    assert second.discard_misc == first.discard_misc + 1
    assert second.line != first.line
    assert [p.name for p in tmp_path.iterdir()] == ["wireless"]  # no temp file left behind


def test_writer_noise_none_prints_the_invalid_sentinel(tmp_path: Path) -> None:
    w = ProcfsWriter(tmp_path / "w", "wlan0")
    w.write(-39, noise_dbm=None)
    row = parse_proc_net_wireless((tmp_path / "w").read_text())["wlan0"]
    assert (row.link, row.level, row.noise, row.noise_updated) == (70, -39, -256, False)


def test_writer_is_atomic_for_a_concurrent_reader(tmp_path: Path) -> None:
    path = tmp_path / "wireless"
    w = ProcfsWriter(path, "wlan1", other_rows={"wlan0": format_proc_row("wlan0")})
    w.write(-50)
    stop = threading.Event()

    def writer() -> None:
        i = 0
        while not stop.is_set():
            w.write(-40 - i % 50)
            i += 1

    th = threading.Thread(target=writer)
    th.start()
    try:
        for _ in range(400):
            rows = parse_proc_net_wireless(path.read_text())
            assert set(rows) == {"wlan0", "wlan1"}
            assert -89 <= rows["wlan1"].level <= -40
    finally:
        stop.set()
        th.join()
    assert w.updates > 1


# ------------------------------------------------------------------------ ProcfsSource


@pytest.fixture
def proc(tmp_path: Path) -> tuple[ProcfsWriter, ProcfsSource]:
    path = tmp_path / "wireless"
    return ProcfsWriter(path, "wlan1"), ProcfsSource("wlan1", path=path)


async def test_procfs_fresh_then_stale_then_fresh_on_repeat(proc: Any) -> None:
    w, src = proc
    w.write(-60)
    s1 = await src.read()
    assert (s1.rssi_dbm, s1.fresh) == (-60.0, True)
    s2 = await src.read()
    assert (s2.rssi_dbm, s2.fresh) == (-60.0, False)
    w.write(-60)  # same value, new update: still fresh
    s3 = await src.read()
    assert (s3.rssi_dbm, s3.fresh) == (-60.0, True)
    w.write(-72)
    s4 = await src.read()
    assert (s4.rssi_dbm, s4.fresh) == (-72.0, True)
    assert src.samples == 3 and src.rejected == 0 and src.errors == 0
    assert src.available and src.last_error is None


async def test_procfs_fresh_only_once_per_update(proc: Any) -> None:
    w, src = proc
    w.write(-61)
    got = [await src.read() for _ in range(5)]
    assert [s.fresh for s in got] == [True, False, False, False, False]
    assert all(s.rssi_dbm == -61.0 for s in got)
    assert got == sorted(got, key=lambda s: s.t)
    # Two sources on the same file judge freshness independently.
    other = ProcfsSource("wlan1", path=w.path)
    assert (await other.read()).fresh


@pytest.mark.parametrize("bogus", [0, -128, -256, 5, -111, -101, 70])
async def test_procfs_rejects_impossible_values(proc: Any, bogus: int) -> None:
    w, src = proc
    w.write(-55)
    assert (await src.read()).fresh
    w.write(bogus)
    s = await src.read()
    assert (s.rssi_dbm, s.fresh) == (None, False)
    assert src.rejected == 1 and src.samples == 1
    s = await src.read()  # re-reading the same bogus update does not count it again
    assert (s.rssi_dbm, s.fresh) == (None, False) and src.rejected == 1
    w.write(-56)
    s = await src.read()
    assert (s.rssi_dbm, s.fresh) == (-56.0, True)


async def test_procfs_u8_biased_level_is_unwrapped(proc: Any) -> None:
    w, src = proc
    w.write(196)  # an out-of-tree driver printing the raw byte
    s = await src.read()
    assert (s.rssi_dbm, s.fresh) == (-60.0, True)


async def test_procfs_vanished_interface_then_back(proc: Any) -> None:
    w, src = proc
    w.write(-50)
    assert (await src.read()).fresh
    w.remove_interface()
    for _ in range(3):
        s = await src.read()
        assert (s.rssi_dbm, s.fresh) == (None, False)
    assert not src.available
    assert src.last_error is not None and "wlan1" in src.last_error
    assert src.errors == 3
    w.write(-50)
    s = await src.read()
    assert (s.rssi_dbm, s.fresh) == (-50.0, True)
    assert src.available and src.last_error is None
    w.unlink()
    s = await src.read()
    assert (s.rssi_dbm, s.fresh, src.available) == (None, False, False)
    assert src.last_error is not None and "does not exist" in src.last_error
    w.write(-51)
    assert (await src.read()).fresh


async def test_procfs_not_associated_row(proc: Any) -> None:
    w, src = proc
    w.write(-50)
    await src.read()
    w.write_disassociated()
    s = await src.read()
    assert (s.rssi_dbm, s.fresh) == (None, False)
    assert src.available and not src.associated
    assert src.rejected == 0 and src.last_error == "not associated"


async def test_procfs_unmarked_level_is_not_fresh(tmp_path: Path) -> None:
    path = tmp_path / "w"
    path.write_text(
        f"{PROC_HEADER_1}\n{PROC_HEADER_2}\n"
        + format_proc_row("wlan1", link=50, level=-60, level_updated=False)
    )
    s = await ProcfsSource("wlan1", path=path).read()
    assert (s.rssi_dbm, s.fresh) == (-60.0, False)


async def test_procfs_garbage_file_is_reported_not_raised(tmp_path: Path) -> None:
    path = tmp_path / "w"
    path.write_bytes(b"\xff\xfe garbage \x00\n wlan1: x y z\n")
    src = ProcfsSource("wlan1", path=path)
    s = await src.read()
    assert (s.rssi_dbm, s.fresh, src.available, src.errors) == (None, False, False, 1)


@pytest.mark.parametrize(
    ("name", "iface", "dbm"),
    [
        ("proc_net_wireless_telegraf_two_ifaces.txt", "wlan0", -50.0),
        ("proc_net_wireless_telegraf_two_ifaces.txt", "wlan1", -39.0),
        ("proc_net_wireless_glances_wlp2s0.txt", "wlp2s0", -59.0),
    ],
)
async def test_procfs_reads_real_captures(name: str, iface: str, dbm: float) -> None:
    src = ProcfsSource(iface, path=FIXTURES / name)
    assert (await src.read()).rssi_dbm == dbm


@pytest.mark.virtual_time
async def test_stream_runs_at_sample_hz_on_the_clock_and_survives_vanishing(tmp_path: Path) -> None:
    clock = LoopClock()
    path = tmp_path / "w"
    w = ProcfsWriter(path, "wlan1")
    src = ProcfsSource("wlan1", path=path, clock=clock)
    got: list[RssiSample] = []
    w.write(-60)
    async for s in src.stream(20.0):
        got.append(s)
        if len(got) == 5:
            w.remove_interface()
        if len(got) == 10:
            w.write(-61)
        if len(got) == 20:
            break
    # On the 0.05 s grid of the clock: 19 periods from first to last, no bursts.
    assert got[-1].t - got[0].t == pytest.approx(19 * 0.05, abs=0.1)
    assert all(b.t > a.t for a, b in itertools.pairwise(got))
    assert got[0].fresh and not any(s.fresh for s in got[1:10])
    assert all(s.rssi_dbm is None for s in got[5:10])
    assert got[10].fresh and got[10].rssi_dbm == -61.0
    assert src.errors == 5


async def test_stream_rejects_a_bad_rate(proc: Any) -> None:
    _, src = proc
    with pytest.raises(ValueError, match="sample_hz"):
        await anext(src.stream(0))


def test_make_source_kinds(tmp_path: Path) -> None:
    assert isinstance(make_source("procfs", "wlan1", path=tmp_path / "w"), ProcfsSource)
    assert make_source("procfs", "wlan1").path == Path("/proc/net/wireless")  # type: ignore[attr-defined]
    iw = make_source("iw", "wlan1", iw_path="/opt/iw")
    assert isinstance(iw, IwSource) and iw.iw_path == "/opt/iw"
    assert isinstance(make_source("nl80211", "wlan1"), Nl80211Source)
    # The daemon passes [wifi] procfs_path whatever the source: only procfs uses it.
    assert isinstance(make_source("nl80211", "wlan1", path="/proc/net/wireless"), Nl80211Source)
    iw = make_source("iw", "wlan1", path="/proc/net/wireless")
    assert isinstance(iw, IwSource) and iw.iw_path == "iw"
    with pytest.raises(ValueError, match="unknown RSSI source"):
        make_source("radiotap", "wlan1")


# ------------------------------------------------------------------------ IwSource

_FAKE_IW = """#!/bin/sh
# A stand-in for iw: logs its argv and replays $DIR/out.txt
DIR='{dir}'
echo "$@" >> "$DIR/argv.log"
if [ -f "$DIR/missing" ]; then
    echo "command failed: No such device (-19)" >&2
    exit 237
fi
if [ -f "$DIR/fail" ]; then
    echo "command failed: Operation not supported (-95)" >&2
    exit 161
fi
if [ -f "$DIR/hang" ]; then
    exec sleep 5
fi
cat "$DIR/out.txt"
"""


class FakeIw:
    def __init__(self, tmp_path: Path) -> None:
        self.dir = tmp_path
        self.path = tmp_path / "iw"
        self.path.write_text(_FAKE_IW.format(dir=tmp_path))
        self.path.chmod(self.path.stat().st_mode | stat.S_IXUSR)

    def reply(self, text: str) -> None:
        (self.dir / "out.txt").write_text(text)

    def flag(self, name: str, on: bool = True) -> None:
        p = self.dir / name
        if on:
            p.touch()
        else:
            p.unlink(missing_ok=True)

    def argv(self) -> list[str]:
        return (self.dir / "argv.log").read_text().splitlines()


def _link(signal: int, rx_packets: int) -> str:
    return (
        f"Connected to f4:f2:6d:22:7c:f0 (on wlan1)\n\tSSID: leader\n\tfreq: 2462\n"
        f"\tRX: 7007190 bytes ({rx_packets} packets)\n\tTX: 20015 bytes (226 packets)\n"
        f"\tsignal: {signal} dBm\n"
    )


@pytest.fixture
def fake_iw(tmp_path: Path) -> FakeIw:
    return FakeIw(tmp_path)


async def test_iw_link_fresh_by_counters(fake_iw: FakeIw) -> None:
    src = IwSource("wlan1", iw_path=str(fake_iw.path))
    fake_iw.reply(_link(-48, 100))
    s = await src.read()
    assert (s.rssi_dbm, s.fresh) == (-48.0, True)
    assert (await src.read()).fresh is False
    fake_iw.reply(_link(-48, 101))  # same signal, more packets: a new frame
    assert (await src.read()).fresh is True
    fake_iw.reply("Not connected.\n")
    s = await src.read()
    assert (s.rssi_dbm, s.fresh, src.associated) == (None, False, False)
    assert fake_iw.argv()[0] == "dev wlan1 link"


async def test_iw_on_fixture_link_text(fake_iw: FakeIw) -> None:
    fake_iw.reply((FIXTURES / "iw_link_opensolo_2447MHz.txt").read_text())
    s = await IwSource("wlan0", iw_path=str(fake_iw.path)).read()
    assert (s.rssi_dbm, s.fresh) == (-37.0, True)


async def test_iw_station_get_bogus_signal_is_rejected(fake_iw: FakeIw) -> None:
    fake_iw.reply((FIXTURES / "station_get_mt76_issue20_bogus_signal.txt").read_text())
    src = IwSource("wlan1", iw_path=str(fake_iw.path), mode="get", bssid="00:13:10:14:C4:FE")
    s = await src.read()
    assert (s.rssi_dbm, s.fresh) == (None, False)
    assert src.rejected == 1 and src.samples == 0 and src.available
    assert fake_iw.argv() == ["dev wlan1 station get 00:13:10:14:C4:FE"]


async def test_iw_station_dump_with_chains(fake_iw: FakeIw) -> None:
    fake_iw.reply(
        (FIXTURES / "station_dump_openwrt_packages_issue16471_chain_signals.txt").read_text()
    )
    src = IwSource("wlan0", iw_path=str(fake_iw.path), mode="dump")
    s = await src.read()
    assert (s.rssi_dbm, s.fresh) == (-57.0, True)
    assert fake_iw.argv() == ["dev wlan0 station dump"]
    # A BSSID filter that matches nothing: not associated to that AP.
    other = IwSource("wlan0", iw_path=str(fake_iw.path), mode="dump", bssid="aa:aa:aa:aa:aa:aa")
    assert (await other.read()).rssi_dbm is None and not other.associated


async def test_iw_no_such_device_then_back(fake_iw: FakeIw) -> None:
    src = IwSource("wlan1", iw_path=str(fake_iw.path))
    fake_iw.reply(_link(-50, 1))
    assert (await src.read()).fresh
    fake_iw.flag("missing")
    s = await src.read()
    assert (s.rssi_dbm, s.fresh, src.available) == (None, False, False)
    assert src.last_error is not None and "No such device" in src.last_error
    fake_iw.flag("missing", on=False)
    s = await src.read()
    assert (s.rssi_dbm, s.fresh, src.available) == (-50.0, True, True)


async def test_iw_other_failures_are_counted(fake_iw: FakeIw, tmp_path: Path) -> None:
    src = IwSource("wlan1", iw_path=str(fake_iw.path), timeout_s=0.3)
    fake_iw.flag("fail")
    s = await src.read()
    assert (s.rssi_dbm, s.fresh) == (None, False)
    assert src.last_error is not None and "exited 161" in src.last_error
    fake_iw.flag("fail", on=False)
    fake_iw.flag("hang")
    s = await src.read()
    assert s.rssi_dbm is None and src.last_error is not None and "timed out" in src.last_error
    fake_iw.flag("hang", on=False)
    fake_iw.reply("something else entirely\n")
    await src.read()
    assert src.last_error is not None and "unrecognised" in src.last_error
    missing = IwSource("wlan1", iw_path=str(tmp_path / "no-such-iw"))
    await missing.read()
    assert missing.last_error is not None and "cannot run" in missing.last_error
    assert src.errors == 3 and missing.errors == 1


def test_iw_mode_validation() -> None:
    with pytest.raises(ValueError, match="bssid"):
        IwSource("wlan1", mode="get")
    with pytest.raises(ValueError, match="mode"):
        IwSource("wlan1", mode="scan")


async def test_iw_from_path_lookup(fake_iw: FakeIw, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", f"{fake_iw.dir}{os.pathsep}{os.environ['PATH']}")
    fake_iw.reply(_link(-44, 7))
    s = await make_source("iw", "wlan1").read()
    assert (s.rssi_dbm, s.fresh) == (-44.0, True)


# ------------------------------------------------------------------------ Nl80211Source


def _station_msg(
    mac: str = "04:f0:21:32:3f:d2",
    *,
    signal: int | None = -60,
    rx_packets: int = 12577,
    beacon_rx: int | None = 2325,
    inactive_ms: int = 70,
    chains: list[int] | None = None,
) -> nl80211cmd:
    """A real NL80211_CMD_NEW_STATION message, encoded and decoded by pyroute2."""
    info: list[list[Any]] = [
        ["NL80211_STA_INFO_INACTIVE_TIME", inactive_ms],
        ["NL80211_STA_INFO_RX_PACKETS", rx_packets],
        ["NL80211_STA_INFO_SIGNAL_AVG", -59],
    ]
    if signal is not None:
        info.append(["NL80211_STA_INFO_SIGNAL", signal])
    if beacon_rx is not None:
        info.append(["NL80211_STA_INFO_BEACON_RX", beacon_rx])
    if chains is not None:
        info.append(["NL80211_STA_INFO_CHAIN_SIGNAL", chains])
    msg = nl80211cmd()
    msg["cmd"] = NL80211_NAMES["NL80211_CMD_NEW_STATION"]
    msg["attrs"] = [
        ["NL80211_ATTR_IFINDEX", 3],
        ["NL80211_ATTR_MAC", mac],
        ["NL80211_ATTR_STA_INFO", {"attrs": info}],
    ]
    msg.encode()
    decoded = nl80211cmd(msg.data)
    decoded.decode()
    return decoded


def test_station_reading_from_a_pyroute2_message() -> None:
    r = station_reading(_station_msg(chains=[-60, -62]))
    assert (
        r.mac,
        r.signal_dbm,
        r.signal_avg_dbm,
        r.rx_packets,
        r.beacon_rx,
        r.inactive_time_ms,
        r.chain_signal_dbm,
    ) == ("04:f0:21:32:3f:d2", -60, -59, 12577, 2325, 70, (-60, -62))


def test_station_reading_from_a_dict_and_from_junk() -> None:
    d = {
        "attrs": [
            ["NL80211_ATTR_MAC", "aa:bb:cc:dd:ee:ff"],
            [
                "NL80211_ATTR_STA_INFO",
                {"attrs": [["NL80211_STA_INFO_SIGNAL", -70], ["NL80211_STA_INFO_RX_PACKETS", 5]]},
            ],
        ]
    }
    r = station_reading(d)
    assert (r.mac, r.signal_dbm, r.rx_packets, r.beacon_rx) == ("aa:bb:cc:dd:ee:ff", -70, 5, None)
    for junk in (None, {}, {"attrs": [["x"]]}, 42, "text"):
        r = station_reading(junk)
        assert r.signal_dbm is None and r.mac is None


def test_observe_stations_picks_the_bssid_or_most_recent() -> None:
    a = _station_msg("aa:aa:aa:aa:aa:aa", signal=-70, inactive_ms=900)
    b = _station_msg("bb:bb:bb:bb:bb:bb", signal=-50, inactive_ms=20)
    assert observe_stations([a, b]).level_dbm == -50
    assert observe_stations([a, b], bssid="AA:AA:AA:AA:AA:AA").level_dbm == -70
    assert observe_stations([]).level_dbm is None
    assert observe_stations([_station_msg(signal=None)]).updated is False


class FakeAsyncIW:
    """Stands in for pyroute2.AsyncIW: replays a script of dumps or exceptions."""

    def __init__(self, script: list[Any]) -> None:
        self.script = script
        self.closed = False
        self.ifindexes: list[int] = []

    async def get_stations(self, ifindex: int) -> AsyncIterator[Any]:
        self.ifindexes.append(ifindex)
        step = self.script.pop(0)
        if isinstance(step, BaseException):
            raise step
        if step == "hang":
            await asyncio.Event().wait()

        async def gen() -> AsyncIterator[Any]:
            for m in step:
                yield m

        return gen()

    def close(self) -> None:
        self.closed = True


def _nl_source(script: list[Any], **kw: Any) -> tuple[Nl80211Source, list[FakeAsyncIW]]:
    made: list[FakeAsyncIW] = []

    def factory() -> FakeAsyncIW:
        made.append(FakeAsyncIW(script))
        return made[-1]

    return Nl80211Source("wlan1", iw_factory=factory, ifindex_of=lambda _: 3, **kw), made


async def test_nl80211_freshness_from_counters() -> None:
    src, made = _nl_source(
        [
            [_station_msg(signal=-60, rx_packets=10, beacon_rx=5)],
            [_station_msg(signal=-60, rx_packets=10, beacon_rx=5)],  # nothing new
            [_station_msg(signal=-60, rx_packets=10, beacon_rx=6)],  # a beacon: fresh
            [_station_msg(signal=-61, rx_packets=11, beacon_rx=6)],
            [_station_msg(signal=0, rx_packets=12, beacon_rx=6)],  # impossible: rejected
            [],  # empty dump
        ]
    )
    got = [await src.read() for _ in range(6)]
    assert [(s.rssi_dbm, s.fresh) for s in got] == [
        (-60.0, True),
        (-60.0, False),
        (-60.0, True),
        (-61.0, True),
        (None, False),
        (None, False),
    ]
    assert (src.samples, src.rejected, src.errors) == (3, 1, 0)
    assert not src.associated and src.last_error == "not associated"
    assert len(made) == 1 and made[0].ifindexes == [3] * 6


async def test_nl80211_enodev_is_reported_and_retried() -> None:
    src, made = _nl_source(
        [
            [_station_msg(signal=-60)],
            NetlinkError(errno.ENODEV),
            [_station_msg(signal=-62, rx_packets=20000)],
        ]
    )
    assert (await src.read()).fresh
    s = await src.read()
    assert (s.rssi_dbm, s.fresh, src.available) == (None, False, False)
    assert src.last_error is not None and "no such device" in src.last_error
    assert made[0].closed
    s = await src.read()
    assert (s.rssi_dbm, s.fresh, src.available) == (-62.0, True, True)
    assert len(made) == 2  # a new netlink socket after the failure


@pytest.mark.virtual_time
async def test_nl80211_timeout_and_odd_errors_never_escape() -> None:
    src, made = _nl_source(
        ["hang", RuntimeError("decoder blew up"), NetlinkError(errno.EOPNOTSUPP), [_station_msg()]],
        clock=LoopClock(),
        timeout_s=0.5,
    )
    s = await src.read()
    assert s.rssi_dbm is None and src.last_error is not None and "timed out" in src.last_error
    await src.read()
    assert src.last_error is not None and "decoder blew up" in src.last_error
    await src.read()
    assert src.last_error is not None and "not a wireless interface" in src.last_error
    assert (await src.read()).fresh
    assert src.errors == 3 and len(made) == 4
    await src.close()
    assert made[-1].closed


async def test_nl80211_missing_interface_by_name() -> None:
    src = Nl80211Source("relaydnone9")  # the real if_nametoindex
    s = await src.read()
    assert (s.rssi_dbm, s.fresh, src.available) == (None, False, False)
    assert src.last_error is not None and "relaydnone9" in src.last_error
    assert src.errors == 1


async def test_nl80211_real_socket_on_a_non_wireless_interface() -> None:
    # Loopback is never a wireless device: whatever the kernel answers (no nl80211
    # family here, ENODEV on a machine with Wi-Fi), it is reported, not raised.
    src = Nl80211Source("lo", timeout_s=2.0)
    s = await src.read()
    await src.close()
    assert (s.rssi_dbm, s.fresh, src.available) == (None, False, False)
    assert src.errors == 1 and src.last_error
