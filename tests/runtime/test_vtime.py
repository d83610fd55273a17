"""The virtual-time loop: timers fire in order at their exact times, no wall time passes,
real sockets still work, and `speed` paces it against the wall clock."""

from __future__ import annotations

import asyncio
import time

import pytest

from relayd.runtime import vtime
from relayd.runtime.vtime import LoopClock, VirtualTimeLoop


def test_timers_fire_in_order_at_their_virtual_times_without_waiting() -> None:
    fired: list[tuple[str, float]] = []

    async def main() -> float:
        clock = LoopClock()
        t0 = clock.now()

        async def sleeper(name: str, s: float) -> None:
            await clock.sleep(s)
            fired.append((name, clock.now() - t0))

        loop = asyncio.get_running_loop()
        loop.call_later(2.5, lambda: fired.append(("call_later", clock.now() - t0)))
        await asyncio.gather(sleeper("b", 3600.0), sleeper("a", 1.0))
        try:
            async with clock.timeout(10.0):
                await asyncio.Event().wait()
        except TimeoutError:
            fired.append(("timeout", clock.now() - t0))
        return clock.now() - t0

    wall = time.monotonic()
    total = vtime.run(main())
    assert time.monotonic() - wall < 2.0
    assert [n for n, _ in fired] == ["a", "call_later", "b", "timeout"]
    assert [t for _, t in fired] == pytest.approx([1.0, 2.5, 3600.0, 3610.0])
    assert total == pytest.approx(3610.0)


def test_a_real_socket_still_answers_while_virtual_time_runs() -> None:
    async def main() -> bytes:
        async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            writer.write(await reader.readline())
            await writer.drain()
            writer.close()

        server = await asyncio.start_server(handle, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]

        async def busy() -> None:  # timers keep the loop jumping meanwhile
            while True:
                await asyncio.sleep(0.1)

        ticker = asyncio.create_task(busy())
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(b"ping\n")
            answer = await asyncio.wait_for(reader.readline(), 3600)
            writer.close()
            return answer
        finally:
            ticker.cancel()
            server.close()
            await server.wait_closed()

    assert vtime.run(main()) == b"ping\n"


def test_speed_paces_virtual_time_against_the_wall_clock() -> None:
    async def main() -> float:
        await asyncio.sleep(1.0)
        return asyncio.get_running_loop().time()

    wall = time.monotonic()
    end = vtime.run(main(), speed=5.0, start_s=0.0)
    elapsed = time.monotonic() - wall
    assert end == pytest.approx(1.0)
    assert 0.15 <= elapsed < 2.0  # 1 virtual second at 5x: about 0.2 s of wall time


def test_bad_speed_is_refused() -> None:
    with pytest.raises(ValueError):
        VirtualTimeLoop(speed=0.0)
