"""A FakeRig in its own process, run by tests/api/test_flood.py.

`python tests/api/rig_proc.py DIR LEADER_X_M LEADER_Y_M CONFIG_JSON`: starts a FakeRig in
DIR with the leader at (X, Y), writes its config (`FakeRig.write_config(**CONFIG_JSON)`)
and prints `{"config": PATH}`. It then samples the fake robot's wheel target every
20 ms and answers one JSON line per command line on stdin:

    vel     {"target_vel_mm_s": V}, the wheel target now
    stops   {"stops": [T, ...]}, the monotonic times of samples whose target was <= 0
            since the previous `stops` (or since `watch`)
    watch   {"watching": true}, from now on samples at or below zero are recorded
    count   {"commands": N, "sips_sent": M}, what the fake robot has received and sent so far
    silences {"silences": [{"wall": [T0, T1], "mono": [M0, M1]}, ...]}: spans since `watch`, in
            wall-clock (time.time, as relayd's log) and monotonic time (as `stops`), in
            which the fake robot itself sent no SIP for longer than SILENCE_S: this process
            was starved by the machine, so the robot really was silent and relayd was right
            to stop it (the test excuses those spans; it does not excuse any other stop)

End of stdin stops the rig and exits. Its own process, so the fake devices keep their
timing however busy the test's own process (and its event loop) is.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time
from pathlib import Path
from typing import Any

SAMPLE_S = 0.02
#: Longer than three SIP periods without a SIP: relayd's lost_after_s (0.5 s) is near.
SILENCE_S = 0.3


async def main(work: Path, leader_xy_m: tuple[float, float], config: dict[str, Any]) -> None:
    from relayd.fakes.rig import FakeRig

    async with FakeRig(work, leader_xy_m=leader_xy_m) as rig:
        path = rig.write_config(**config)
        print(json.dumps({"config": str(path)}), flush=True)
        stops: list[float] = []
        silences: list[dict[str, list[float]]] = []
        watching = False

        async def sample() -> None:
            sips, sip_wall, sip_mono = rig.robot.sips_sent, time.time(), time.monotonic()
            while True:
                if watching and rig.robot.target_vel_mm_s <= 0:
                    stops.append(time.monotonic())
                if rig.robot.sips_sent != sips:
                    wall, mono = time.time(), time.monotonic()
                    if watching and mono - sip_mono > SILENCE_S:
                        silences.append({"wall": [sip_wall, wall], "mono": [sip_mono, mono]})
                    sips, sip_wall, sip_mono = rig.robot.sips_sent, wall, mono
                await asyncio.sleep(SAMPLE_S)

        sampler = asyncio.create_task(sample())
        try:
            while line := (await asyncio.to_thread(sys.stdin.readline)).strip():
                if line == "vel":
                    answer: dict[str, Any] = {"target_vel_mm_s": rig.robot.target_vel_mm_s}
                elif line == "watch":
                    watching = True
                    answer = {"watching": True}
                elif line == "count":
                    answer = {"commands": len(rig.robot.commands), "sips_sent": rig.robot.sips_sent}
                elif line == "stops":
                    answer = {"stops": stops[:]}
                    stops.clear()
                elif line == "silences":
                    answer = {"silences": silences[:]}
                else:
                    answer = {"error": f"unknown command {line!r}"}
                print(json.dumps(answer), flush=True)
        finally:
            sampler.cancel()


if __name__ == "__main__":
    asyncio.run(
        main(Path(sys.argv[1]), (float(sys.argv[2]), float(sys.argv[3])), json.loads(sys.argv[4]))
    )
