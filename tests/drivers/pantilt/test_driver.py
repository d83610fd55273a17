"""The pan-tilt drivers against the byte-true fakes.

Unit tests use in-memory links in virtual time (`virtual_time`); a few integration
tests keep real pseudo-terminals on a 10x clock (replug, a second writer on the tty).
"""

from __future__ import annotations

import asyncio
import os
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from drivers.pantilt import PanTilt, PanTiltError, ServoCalibration, make_pantilt
from drivers.pantilt.fake import FakeMaestro, FakeSsc32
from drivers.pantilt.maestro import MaestroPanTilt
from drivers.transport.backoff import Backoff
from drivers.transport.clock import Clock
from drivers.transport.memlink import LinkFaults
from tests.support import LoopClock, until

SPEED = 10.0  # clock runs 10x faster than wall time
FAKES = {"maestro": FakeMaestro, "ssc32": FakeSsc32}
#: Read-back resolution: quarter-us on the Maestro, 10 us (~1.8 deg) on the SSC-32.
TOL_DEG = {"maestro": 0.1, "ssc32": 1.0}


@dataclass
class Rig:
    protocol: str
    clock: Clock
    fake: FakeMaestro | FakeSsc32
    pt: PanTilt
    task: asyncio.Task[None]
    tol: float


async def flush(pt: PanTilt) -> None:
    """Commands have no reply: a query answered means the fake has read all before it."""
    await pt.is_moving()


VT = pytest.mark.virtual_time


async def make_rig(protocol: str, tmp_path: Path, kind: str = "memory", **options: float) -> Rig:
    clock: Clock = LoopClock() if kind == "memory" else Clock(SPEED)
    fake = FAKES[protocol](clock=clock)
    if kind == "memory":
        path = fake.serve_memory(f"{protocol}-servo")
    else:
        path = fake.serve_pty(tmp_path / f"{protocol}-servo")
    opts: dict[str, float] = {"reply_timeout_s": 3.0, "poll_s": 1000.0}
    opts.update(options)
    pt = make_pantilt(
        protocol,
        path,
        None,
        {0: ServoCalibration(), 1: ServoCalibration(pulse_us=(2000, 1500, 1000))},
        clock=clock,
        **opts,
    )
    task = asyncio.create_task(pt.run())
    await until(lambda: pt.connected)
    return Rig(protocol, clock, fake, pt, task, TOL_DEG[protocol])


@pytest.fixture(params=["maestro", "ssc32"])
async def rig(request: pytest.FixtureRequest, tmp_path: Path) -> AsyncIterator[Rig]:
    r = await make_rig(request.param, tmp_path)
    yield r
    await close_rig(r)


async def close_rig(r: Rig) -> None:
    await r.pt.close()
    await asyncio.wait_for(r.task, 5)
    r.fake.close()


@VT
async def test_set_and_read_back_angle(rig: Rig) -> None:
    assert await rig.pt.set_angle(0, 30) == 30
    await flush(rig.pt)
    assert await rig.pt.get_angle(0) == pytest.approx(30, abs=rig.tol)
    assert rig.fake.target_us(0) == pytest.approx(1500 + 500 / 3, abs=0.5)
    # Channel 1 is mounted reversed: +30 deg is a shorter pulse.
    await rig.pt.set_angle(1, 30)
    await flush(rig.pt)
    assert rig.fake.target_us(1) == pytest.approx(1500 - 500 / 3, abs=0.5)
    assert await rig.pt.get_angle(1) == pytest.approx(30, abs=rig.tol)
    assert not await rig.pt.is_moving()
    assert rig.pt.counters["timeouts"] == 0 and rig.pt.counters["errors"] == 0


@VT
async def test_position_evolves_at_the_slew_rate(rig: Rig) -> None:
    pt, fake, clock = rig.pt, rig.fake, rig.clock
    await pt.set_angle(0, 0)
    await pt.set_speed(0, 90)  # 90 deg/s = 500 us/s with 1000 us per 180 deg
    t0 = clock.now()
    await pt.set_angle(0, 45)  # 250 us: half a second of clock time
    assert await pt.is_moving()
    await clock.sleep(0.25)
    mid = await pt.get_angle(0)
    assert 8 < mid < 40
    elapsed = clock.now() - t0
    assert fake.position_us(0) == pytest.approx(1500 + 500 * min(elapsed, 0.5), abs=30)
    assert await pt.wait_stopped(5.0)
    took = clock.now() - t0
    assert 0.45 < took < 2.0
    assert not await pt.is_moving()
    assert await pt.get_angle(0) == pytest.approx(45, abs=rig.tol)


@VT
async def test_out_of_limit_angles_are_clamped_never_sent(rig: Rig) -> None:
    pt, fake = rig.pt, rig.fake
    assert await pt.set_angle(0, 120) == 90
    assert await pt.set_angle(1, -500) == -90
    assert pt.counters["clamped"] == 2
    await flush(pt)
    assert fake.target_us(0) == 2000 and fake.target_us(1) == 2000
    assert await pt.get_angle(0) == pytest.approx(90, abs=rig.tol)
    with pytest.raises(ValueError):
        await pt.set_angle(0, float("nan"))
    with pytest.raises(PanTiltError):
        await pt.set_angle(7, 0)  # not configured
    assert pt.limits(0) == (-90, 90)


@VT
async def test_two_channels_interleaved_without_crosstalk(rig: Rig) -> None:
    pt = rig.pt

    async def worker(channel: int, angles: list[float]) -> None:
        for a in angles:
            await pt.set_angle(channel, a)
            assert await pt.get_angle(channel) == pytest.approx(a, abs=rig.tol)
            await asyncio.sleep(0)

    await asyncio.gather(
        worker(0, [-80, -40, 0, 40, 80] * 3),
        worker(1, [70, 35, -35, -70, 10] * 3),
        *(pt.is_moving() for _ in range(10)),
    )
    assert pt.counters["stray_bytes"] == 0 and pt.counters["timeouts"] == 0


@VT
@pytest.mark.parametrize("protocol", ["maestro", "ssc32"])
async def test_silent_controller_times_out_then_reconnects(tmp_path: Path, protocol: str) -> None:
    r = await make_rig(protocol, tmp_path, reply_timeout_s=1.0)
    try:
        r.fake.silent = True
        with pytest.raises(PanTiltError, match="no reply"):
            await r.pt.get_angle(0)
        assert r.pt.counters["timeouts"] == 1
        assert r.pt.connected
        assert "no reply" in (r.pt.last_error or "")
        # The last proof of life is the handshake's reply, not the unanswered request.
        answered_t = r.pt.last_reply_t
        assert answered_t is not None and answered_t < r.clock.now() - 0.9
        for _ in range(2):
            with pytest.raises(PanTiltError):
                await r.pt.is_moving()
        # Three unanswered requests in a row: the link is dropped.
        assert not r.pt.connected
        with pytest.raises(PanTiltError, match="not connected"):
            await r.pt.set_angle(0, 10)
        r.fake.silent = False
        await until(lambda: r.pt.connected)
        assert r.pt.counters["reconnects"] == 1
        assert await r.pt.set_angle(0, -20) == -20
        assert await r.pt.get_angle(0) == pytest.approx(-20, abs=r.tol)
        assert r.pt.last_reply_t is not None and r.pt.last_reply_t > answered_t
    finally:
        await r.pt.close()
        await asyncio.wait_for(r.task, 5)
        r.fake.close()


@VT
async def test_reconnects_after_hang_up(rig: Rig) -> None:
    await _reconnects_after_hang_up(rig)


@pytest.mark.parametrize("protocol", ["maestro", "ssc32"])
async def test_reconnects_after_hang_up_over_a_pty(protocol: str, tmp_path: Path) -> None:
    r = await make_rig(protocol, tmp_path, "pty")
    try:
        await _reconnects_after_hang_up(r)
    finally:
        await close_rig(r)


async def _reconnects_after_hang_up(rig: Rig) -> None:
    pt, fake = rig.pt, rig.fake
    await pt.set_speed(0, 45)
    await pt.set_angle(0, 10)
    await flush(pt)  # bytes still in the pty when the cable is pulled are lost, as on hardware
    fake.hang_up()
    await until(lambda: not pt.connected)
    with pytest.raises(PanTiltError):
        await pt.get_angle(0)
    assert pt.last_error is not None
    fake.reappear()
    await until(lambda: pt.connected)
    assert pt.counters["reconnects"] == 1
    await flush(pt)
    if isinstance(fake, FakeMaestro):
        # The slew limit is sent again on reconnect (a replugged Maestro forgets it).
        assert fake.commands.count(("set_speed", 0, 10)) == 2, str(fake.commands)
    await pt.set_angle(0, -10)
    assert await pt.wait_stopped(5.0)  # still slewing at 45 deg/s after the reconnect
    assert await pt.get_angle(0) == pytest.approx(-10, abs=rig.tol)


@VT
async def test_not_connected_is_an_error() -> None:
    pt = make_pantilt("ssc32", "/nonexistent/tty", None, {0: ServoCalibration()})
    with pytest.raises(PanTiltError, match="not connected"):
        await pt.set_angle(0, 0)
    with pytest.raises(PanTiltError):
        await pt.is_moving()
    await pt.set_speed(0, 30)  # remembered for the connection
    assert pt.speed_deg_s(0) == 30
    with pytest.raises(ValueError):
        make_pantilt("ptu", "/dev/null", None, {0: ServoCalibration()})
    with pytest.raises(ValueError):  # the SSC-32 cannot make 3000 us
        make_pantilt("ssc32", "/dev/null", None, {0: ServoCalibration(pulse_us=(1000, 2000, 3000))})


async def test_run_backs_off_while_the_port_is_missing(tmp_path: Path) -> None:
    clock = Clock(SPEED)
    link = tmp_path / "servo"
    pt = make_pantilt(
        "maestro", str(link), None, {0: ServoCalibration()}, clock=clock, poll_s=1000.0
    )
    task = asyncio.create_task(pt.run())
    await until(lambda: pt.counters["errors"] >= 2)
    assert "cannot open" in (pt.last_error or "")
    fake = FakeMaestro(clock=clock)
    fake.serve_pty(link)
    await until(lambda: pt.connected)
    assert pt.counters["reconnects"] == 0  # the first connection is not a reconnect
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert not pt.connected
    fake.close()


async def test_maestro_error_bits_reported(tmp_path: Path) -> None:
    r = await make_rig("maestro", tmp_path, "pty", poll_s=0.5)
    pt = r.pt
    assert isinstance(pt, MaestroPanTilt)
    try:
        assert await pt.get_errors() == ()
        # Another writer puts an unknown command byte on the wire: the Maestro flags it.
        fd = os.open(r.fake.path, os.O_WRONLY | os.O_NOCTTY)
        try:
            os.write(fd, b"\x80")
        finally:
            os.close(fd)
        # The periodic poll (every 0.5 clock s) picks it up and names the bit.
        await until(lambda: pt.maestro_errors == ("serial_protocol",))
        assert pt.counters["device_errors"] == 1
        assert "serial_protocol" in (pt.last_error or "")
        assert await pt.get_errors() == ()  # reading cleared it
        assert pt.maestro_errors == ("serial_protocol",)  # last report stays visible
        await pt.go_home()
        await pt.set_acceleration(0, 100)
        await flush(pt)
        assert isinstance(r.fake, FakeMaestro)
        assert r.fake.accel_units[0] == 2  # 100 deg/s^2 * 5.56 us/deg / 312.5
    finally:
        await pt.close()
        await asyncio.wait_for(r.task, 5)
        r.fake.close()


class GarblingSsc32(FakeSsc32):
    """An SSC-32 behind a noisy cable: the next reply is replaced by `garble`."""

    garble: bytes = b""

    def _reply(self, data: bytes) -> None:
        if self.garble:
            data, self.garble = self.garble, b""
        super()._reply(data)


@VT
async def test_garbled_and_unsolicited_bytes_are_counted_not_fatal(tmp_path: Path) -> None:
    clock = LoopClock()
    fake = GarblingSsc32(clock=clock)
    pt = make_pantilt(
        "ssc32",
        fake.serve_memory("servo"),
        None,
        {0: ServoCalibration()},
        clock=clock,
        reply_timeout_s=3.0,
        poll_s=1000.0,
    )
    task = asyncio.create_task(pt.run())
    try:
        await until(lambda: pt.connected)
        fake.garble = b"x"
        with pytest.raises(PanTiltError, match="bad reply"):
            await pt.is_moving()
        assert pt.counters["errors"] == 1 and pt.connected
        # Bytes nobody asked for are dropped and counted; the next answer is still right.
        fake.send_noise(b"+++")
        await until(lambda: pt.counters["stray_bytes"] == 3)
        await pt.set_angle(0, 45)
        assert await pt.get_angle(0) == pytest.approx(45, abs=1.0)
        assert not await pt.is_moving()
    finally:
        await pt.close()
        await asyncio.wait_for(task, 5)
        fake.close()


@VT
async def test_close_ends_run_even_while_backing_off(tmp_path: Path) -> None:
    pt = make_pantilt(
        "maestro",
        str(tmp_path / "absent"),
        None,
        {0: ServoCalibration()},
        backoff=Backoff(initial_s=60.0, maximum_s=60.0),
    )
    task = asyncio.create_task(pt.run())
    await until(lambda: pt.counters["errors"] >= 1)
    await pt.close()
    await asyncio.wait_for(task, 2)  # returned, did not sit out the 60 s backoff
    assert not pt.connected


@VT
@pytest.mark.parametrize("protocol", ["maestro", "ssc32"])
async def test_replies_split_into_single_bytes_and_delayed_still_answer(protocol: str) -> None:
    clock = LoopClock()
    fake = FAKES[protocol](clock=clock)
    one_byte = LinkFaults(chunk_bytes=1, delay_s=0.01)
    url = fake.serve_memory(
        f"{protocol}-slow", faults_to_driver=one_byte, faults_to_device=LinkFaults(chunk_bytes=1)
    )
    pt = make_pantilt(
        protocol,
        url,
        None,
        {0: ServoCalibration()},
        clock=clock,
        reply_timeout_s=1.0,
        poll_s=1000.0,
    )
    task = asyncio.create_task(pt.run())
    try:
        await until(lambda: pt.connected)
        for angle in (-60.0, 0.0, 45.0):
            await pt.set_angle(0, angle)
            assert await pt.get_angle(0) == pytest.approx(angle, abs=TOL_DEG[protocol])
        assert pt.counters["timeouts"] == 0 and pt.counters["stray_bytes"] == 0
    finally:
        await pt.close()
        await asyncio.wait_for(task, 5)
        fake.close()
