"""The live Foxglove server, checked on the wire by a client written here.

The client is aiohttp's WebSocket client speaking the Foxglove WebSocket protocol
itself (subprotocol `foxglove.sdk.v1`: JSON `serverInfo` and `advertise`, a JSON
`subscribe`, binary message-data frames decoded here byte by byte), so these tests
check what a Foxglove app receives, not the SDK against itself:

- the channels advertised are the recorder's, with its schemas byte for byte;
- after subscribing, messages arrive on each kind of channel, each validating against
  the schema its channel advertised, stamped with wall-clock log times;
- a client that connects, subscribes to everything and never reads again does not
  slow the daemon: the robot drives and scans on, another client keeps getting fresh
  data, the daemon's live subscriber never falls behind, and shutdown stays prompt.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import fcntl
import json
import os
import socket
import struct
import termios
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import jsonschema
import pytest

from drivers.arcos.codec import Command
from relayd.config.load import parse_settings
from relayd.config.model import ConfigError, FoxgloveSettings
from relayd.core.vocab import DriveState
from relayd.daemon import Daemon
from relayd.fakes.rig import FakeRig
from relayd.record import codec
from relayd.record.live import CLIENT_BACKLOG, SUBPROTOCOL, channel_specs
from relayd.record.recorder import Recorder
from relayd.runtime.vtime import LoopClock
from tests.support import running, until

pytestmark = pytest.mark.slow

SCAN = {"samples": 9, "width_deg": 120, "settle_s": 0.02}
PANTILT = {"speed_deg_s": 1000}
BASE = {"control": {"rear_link": "ignore"}}
OP_MESSAGE_DATA = 0x01
#: Wall time a stalled client stays connected while the robot drives (SIPs at 40 Hz).
STALLED_WINDOW_S = 6.0


# -- config ------------------------------------------------------------------------------


def test_config_defaults_off_and_on_loopback() -> None:
    s = parse_settings(BASE)
    assert s.foxglove == FoxgloveSettings(enabled=False, bind="127.0.0.1", port=8765)


@pytest.mark.parametrize(
    ("section", "expected"),
    [
        ({"enabled": "yes"}, "foxglove.enabled"),
        ({"bind": "robot.local"}, "foxglove.bind: 'robot.local' is not an IP address"),
        ({"port": 70000}, "foxglove.port"),
        ({"prot": 8766}, "foxglove.prot: unknown key (did you mean 'port'?)"),
        ({"enabled": True, "port": 8080}, "foxglove.port: 8080 is also api.port"),
    ],
)
def test_config_errors_name_the_key(section: dict[str, Any], expected: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_settings({**BASE, "foxglove": section})
    assert any(e.startswith(expected) for e in err.value.errors), err.value.errors


def test_the_live_channels_are_the_recorders(tmp_path: Path) -> None:
    """One source of truth: each topic, schema name and schema byte string as the recorder writes it."""
    settings = parse_settings(
        {**BASE, "record": {"enabled": True, "path": str(tmp_path / "r.mcap")}}
    )

    class Bus:
        def subscribe_with_actions(self, name: str, maxlen: int = 1) -> Any:
            return None

        def unsubscribe(self, sub: Any) -> None:
            pass

    class Clock:
        def now(self) -> float:
            return 0.0

    rec = Recorder(Bus(), settings, Clock())  # type: ignore[arg-type]
    recorded = [
        rec._spec(cls) for cls in (*codec.EVENT_TYPES.values(), *codec.ACTION_TYPES.values())
    ]
    recorded += list(rec._view_specs.values())
    assert channel_specs() == recorded
    assert {
        "/robot/sip",
        "/robot/pose",
        "/wifi/rssi",
        "/scan/sample",
        "/action/scan_result",
        "/state",
        "/action/decision",
        "/action/wheels",
        "/log",
    } <= {s.topic for s in recorded}


# -- the wire ------------------------------------------------------------------------------


def parse_frame(data: bytes) -> tuple[int, int, bytes]:
    """A message-data frame: (subscription id, log time ns, payload)."""
    assert data[0] == OP_MESSAGE_DATA, f"not a message-data frame: opcode {data[0]}"
    sub_id, log_time = struct.unpack_from("<IQ", data, 1)
    return sub_id, log_time, data[13:]


class WireClient:
    """A Foxglove WebSocket client: handshake, serverInfo, advertise, subscribe, frames."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.server_info: dict[str, Any] = {}
        self.channels: dict[int, dict[str, Any]] = {}
        self.validators: dict[int, jsonschema.Draft202012Validator] = {}
        self.subs: dict[int, int] = {}  # subscription id -> channel id
        self.received: dict[str, list[tuple[int, dict[str, Any]]]] = {}

    async def hello(self) -> None:
        while not self.server_info or not self.channels:
            msg = await self.ws.receive(timeout=10)
            assert msg.type == aiohttp.WSMsgType.TEXT, msg
            doc = json.loads(msg.data)
            if doc["op"] == "serverInfo":
                self.server_info = doc
            elif doc["op"] == "advertise":
                for ch in doc["channels"]:
                    self.channels[ch["id"]] = ch
                    self.validators[ch["id"]] = jsonschema.Draft202012Validator(
                        json.loads(ch["schema"])
                    )

    def channel_id(self, topic: str) -> int:
        return next(cid for cid, ch in self.channels.items() if ch["topic"] == topic)

    async def subscribe_all(self) -> None:
        self.subs = {100 + k: cid for k, cid in enumerate(sorted(self.channels))}
        await self.ws.send_str(
            json.dumps(
                {
                    "op": "subscribe",
                    "subscriptions": [
                        {"id": sid, "channelId": cid} for sid, cid in self.subs.items()
                    ],
                }
            )
        )

    async def read(self) -> None:
        """Decode and validate every frame until the socket closes."""
        async for msg in self.ws:
            if msg.type != aiohttp.WSMsgType.BINARY:
                continue
            sub_id, log_time, payload = parse_frame(msg.data)
            cid = self.subs[sub_id]
            doc = json.loads(payload)
            self.validators[cid].validate(doc)
            self.received.setdefault(self.channels[cid]["topic"], []).append((log_time, doc))


@contextlib.asynccontextmanager
async def live_relay(
    tmp_path: Path, leader_xy_m: tuple[float, float] = (6.0, 1.0), sip_period_s: float = 0.1
) -> AsyncIterator[tuple[FakeRig, Daemon, str]]:
    """A daemon on the fake rig (real clock, this process) with the live server on a free port."""
    rig = FakeRig(tmp_path, leader_xy_m=leader_xy_m)
    rig.robot.sip_period_s = sip_period_s
    async with rig:
        doc = rig.config_doc(
            scan=SCAN,
            pantilt=PANTILT,
            robot={"display_name": "relay one"},
            log={"level": "warning"},
        )
        doc["foxglove"] = {"enabled": True, "port": 0}
        daemon = Daemon(parse_settings(doc), env=rig.env)
        async with running(daemon):
            await until(lambda: daemon.live is not None and daemon.live.port, "the live server", 30)
            assert daemon.live is not None
            yield rig, daemon, f"ws://127.0.0.1:{daemon.live.port}/"


@contextlib.asynccontextmanager
async def wire_client(url: str) -> AsyncIterator[WireClient]:
    async with (
        aiohttp.ClientSession() as session,
        session.ws_connect(url, protocols=[SUBPROTOCOL], max_msg_size=0) as ws,
    ):
        assert ws.protocol == SUBPROTOCOL
        client = WireClient(ws)
        await client.hello()
        yield client


def forward_commands(rig: FakeRig) -> int:
    return sum(
        1
        for cmd, arg in rig.robot.commands
        if cmd == Command.VEL and isinstance(arg, int) and arg > 0
    )


async def test_advertise_subscribe_and_messages_on_the_wire(tmp_path: Path) -> None:
    async with live_relay(tmp_path) as (rig, daemon, url), wire_client(url) as client:
        assert client.server_info["name"] == "relay one"
        assert (
            client.server_info["capabilities"] == []
        )  # read-only: no publishing, services or parameters
        specs = {s.topic: s for s in channel_specs()}
        assert {ch["topic"] for ch in client.channels.values()} == set(specs)
        for ch in client.channels.values():
            spec = specs[ch["topic"]]
            assert (ch["encoding"], ch["schemaEncoding"]) == ("json", "jsonschema")
            assert ch["schemaName"] == spec.schema_name
            assert ch["schema"].encode() == spec.schema  # the very bytes a recording stores
        # Connected but not subscribed: the daemon encodes nothing for it.
        live = daemon.live
        assert live is not None
        await until(lambda: live.events > 50, "events on the bus", 30)
        assert live.sent == 0
        await client.subscribe_all()
        reader = asyncio.create_task(client.read())
        want = {
            "/robot/sip",
            "/robot/pose",
            "/wifi/rssi",
            "/scan/sample",
            "/action/scan_result",
            "/action/decision",
            "/action/wheels",
            "/state",
            "/tick",
        }
        await until(
            lambda: want <= set(client.received) or reader.done(),
            f"messages on {sorted(want)} (got {sorted(client.received)})",
            60,
        )
        assert not reader.done(), reader
        now = time.time_ns()
        for topic in want:
            for log_time, _doc in client.received[topic]:
                assert abs(log_time - now) < 30e9, (
                    topic,
                    log_time,
                    now,
                )  # wall-clock, like a recording
        # /state is latched: the current values first, whenever the client subscribed.
        first_keys = [doc["key"] for _t, doc in client.received["/state"][:3]]
        assert set(first_keys) == {"mode", "drive_state", "reason"}
        # seq counts the bus's events: strictly increasing on each event channel.
        seqs = [doc["seq"] for _t, doc in client.received["/robot/sip"]]
        assert seqs == sorted(set(seqs))
        decisions = client.received["/action/decision"]
        assert all("i" in doc for _t, doc in decisions)
        sip = client.received["/robot/sip"][-1][1]
        assert sip["sip"]["x_mm"] == pytest.approx(rig.robot.x_mm, abs=600)
        assert len(sip["sonar_mm"]) == 16  # the sonar ring rides on /robot/sip, as in a recording
        # A second viewer joining later gets the current state at once too.
        async with wire_client(url) as late:
            state_id = late.channel_id("/state")
            late.subs = {1: state_id}
            await late.ws.send_str(
                json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": state_id}]})
            )
            late_reader = asyncio.create_task(late.read())
            await until(lambda: len(late.received.get("/state", [])) >= 3, "the latched /state", 30)
            assert {doc["key"] for _t, doc in late.received["/state"][:3]} == {
                "mode",
                "drive_state",
                "reason",
            }
            assert late.received["/state"][1][1] == {
                "key": "drive_state",
                "value": str(daemon.state.state),
            }
            late_reader.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await late_reader
        reader.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reader
        assert live.dropped == 0


async def test_the_subprotocol_names_a_client_may_offer(tmp_path: Path) -> None:
    """docs/RECORDING.md says: the current name is accepted, a client knowing only the old one is refused."""
    async with live_relay(tmp_path) as (_rig, _daemon, url), aiohttp.ClientSession() as session:
        async with session.ws_connect(url, protocols=["foxglove.websocket.v1", SUBPROTOCOL]) as ws:
            assert ws.protocol == SUBPROTOCOL
            assert json.loads((await ws.receive(timeout=10)).data)["op"] == "serverInfo"
        with pytest.raises(aiohttp.WSServerHandshakeError) as err:
            await session.ws_connect(url, protocols=["foxglove.websocket.v1"])
        assert err.value.status == 400


def raw_stalled_client(port: int, channel_ids: list[int]) -> socket.socket:
    """Connect, subscribe to every channel, and never read again (a tiny receive buffer)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.settimeout(10)
    sock.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        (
            f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
            f"Sec-WebSocket-Protocol: {SUBPROTOCOL}\r\n\r\n"
        ).encode()
    )
    head = b""
    while b"\r\n\r\n" not in head:
        head += sock.recv(1)
    assert head.startswith(b"HTTP/1.1 101"), head
    payload = json.dumps(
        {
            "op": "subscribe",
            "subscriptions": [{"id": 1 + k, "channelId": cid} for k, cid in enumerate(channel_ids)],
        }
    ).encode()
    mask = os.urandom(4)
    n = len(payload)
    header = bytes([0x81]) + (
        bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack(">H", n)
    )
    sock.sendall(header + mask + bytes(b ^ mask[k % 4] for k, b in enumerate(payload)))
    return sock


def unread_bytes(sock: socket.socket) -> int:
    buf = fcntl.ioctl(sock.fileno(), termios.FIONREAD, b"\0\0\0\0")
    return int(struct.unpack("i", buf)[0])


async def test_a_client_that_never_reads_does_not_stall_the_robot(tmp_path: Path) -> None:
    # A far leader: the relay drives the whole test. SIPs at 40 Hz: four times a robot's data.
    async with live_relay(tmp_path, leader_xy_m=(40.0, 3.0), sip_period_s=0.025) as (
        rig,
        daemon,
        url,
    ):
        live = daemon.live
        assert live is not None
        st = daemon.state
        await until(lambda: forward_commands(rig) > 0, "the relay driving", 60)
        async with wire_client(url) as good:
            stalled = raw_stalled_client(live.port or 0, sorted(good.channels))
            await good.subscribe_all()
            reader = asyncio.create_task(good.read())
            await until(
                lambda: unread_bytes(stalled) > 1000, "data queued at the stalled client", 30
            )
            sent, x, scans = forward_commands(rig), rig.robot.x_mm, st.scan_count
            started = time.monotonic()
            # Data piles up at the stalled client while the robot works on. (At this rate,
            # ~50 kB/s, the kernel's socket buffers would take a minute to fill: that
            # overflow, and the SDK's backlog dropping, is the virtual-time test below. A
            # 12 s window here filled nothing more than this one does.)
            await until(
                lambda: (
                    time.monotonic() - started > STALLED_WINDOW_S
                    and forward_commands(rig) > sent + 20
                    and rig.robot.x_mm > x + 500
                    and st.scan_count > scans + 2
                ),
                "the robot driving and scanning on",
                60,
            )
            assert st.state is DriveState.DRIVING
            # The other client still gets the present, not a backlog: a SIP under 2 s old
            # reaches it (waited for: on a loaded machine its reader may be a beat behind).
            sips = good.received["/robot/sip"]
            await until(
                lambda: time.time_ns() - sips[-1][0] < 2e9, "a fresh SIP at the good client", 10
            )
            assert len(sips) > STALLED_WINDOW_S * 20
            assert not reader.done()
            # The daemon's live subscriber kept up: the SDK never blocked its task.
            assert live.dropped == 0
            reader.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await reader
        stalled_unread = unread_bytes(stalled)
        t0 = time.monotonic()  # the daemon's shutdown, the stalled client still connected
    stop_s = time.monotonic() - t0
    stalled.close()
    assert stalled_unread > 1000
    assert stop_s < 5.0, "shutdown waited on the stalled client"


async def test_a_taken_port_is_a_config_error_naming_the_key(tmp_path: Path) -> None:
    blocker = socket.socket()
    blocker.bind(("127.0.0.1", 0))
    blocker.listen()
    port = blocker.getsockname()[1]
    try:
        async with FakeRig(tmp_path) as rig:
            doc = rig.config_doc(log={"level": "warning"})
            doc["foxglove"] = {"enabled": True, "port": port}
            daemon = Daemon(parse_settings(doc), env=rig.env)
            with pytest.raises(ConfigError) as err:
                await daemon.run()
            assert err.value.errors[0].startswith(
                f"foxglove.port: cannot listen on 127.0.0.1:{port}"
            )
            assert not rig.robot.commands or forward_commands(rig) == 0
    finally:
        blocker.close()


def tcp_wmem_max() -> int:
    """The most a kernel socket send buffer may grow to (what can hide a stalled reader)."""
    return int(Path("/proc/sys/net/ipv4/tcp_wmem").read_text().split()[2])


@pytest.mark.virtual_time
async def test_on_virtual_time_a_stalled_client_overflows_its_backlog_and_the_robot_drives_on(
    tmp_path: Path,
) -> None:
    """More data than every buffer between the server and a stalled client can hold.

    On virtual time the rig runs flat out, so minutes of a robot's data pass in seconds:
    past the kernel's socket buffers the SDK's per-client backlog must drop (or the SDK
    drops the client). If logging a message ever waited for that client, this loop
    would hang here for good instead.
    """
    rig = FakeRig(tmp_path, leader_xy_m=(200.0, 3.0), clock=LoopClock(), links="memory")
    rig.robot.sip_period_s = 0.025
    async with rig:
        doc = rig.config_doc(scan=SCAN, pantilt=PANTILT, log={"level": "warning"})
        doc["foxglove"] = {"enabled": True, "port": 0}
        daemon = Daemon(parse_settings(doc), env=rig.env, clock=rig.clock)
        async with running(daemon):
            await until(lambda: daemon.live is not None and daemon.live.port, "the live server", 30)
            live = daemon.live
            assert live is not None
            stalled = raw_stalled_client(live.port or 0, sorted(live.channel_ids().values()))
            try:
                await until(lambda: forward_commands(rig) > 0, "the relay driving", 60)
                x0, t0 = rig.robot.x_mm, rig.clock.now()

                def can_hold() -> int:
                    """The kernel's send buffer, both receive buffers, a full SDK backlog of the largest messages."""
                    return tcp_wmem_max() + 2 * 65536 + CLIENT_BACKLOG * live.max_message_bytes

                await until(
                    lambda: live.sent_bytes > 1.1 * can_hold(),
                    "more data than the buffers hold",
                    600,
                )
                moved_mm = rig.robot.x_mm - x0
                # Driving at v_max the whole time: what it covered is what the virtual time allowed.
                assert moved_mm > 0.5 * 400.0 * (rig.clock.now() - t0)
                assert daemon.state.state is DriveState.DRIVING
                assert live.dropped == 0
            finally:
                stalled.close()


@pytest.mark.timeout(180)
async def test_the_benchmark_measures_with_a_viewer_connected() -> None:
    """bench/foxglove_live.py in a tiny configuration: its client really receives, its rows are real."""
    from bench import foxglove_live
    from bench.common import free_port
    from bench.latency import measure

    med, _p99, sent = await foxglove_live._loop_cost(200, True)
    assert sent > 200 and 0 < med < 10_000
    data = await measure(cycles=20, load_rps=0.0, foxglove_port=free_port(), viewer=True)
    viewer = data["viewer"]
    assert viewer["channels"] == len(channel_specs()) and viewer["messages"] > 20
    # relayd's histogram counted the cycles' commands. Not all 20: on a loaded machine
    # relayd reads some SIPs together and commands only the newer one (superseded), so a
    # share of the cycles, as tests/bench/test_smoke.py has it.
    alone = data["alone"]
    assert alone["cycles"] // 2 <= alone["in_relayd"]["count"] <= alone["cycles"] + 20, alone


async def test_an_address_not_on_this_machine_names_foxglove_bind(tmp_path: Path) -> None:
    async with FakeRig(tmp_path) as rig:
        doc = rig.config_doc(log={"level": "warning"})
        doc["foxglove"] = {
            "enabled": True,
            "bind": "192.0.2.1",
            "port": 0,
        }  # TEST-NET-1: never local
        daemon = Daemon(parse_settings(doc), env=rig.env)
        with pytest.raises(ConfigError) as err:
            await daemon.run()
        assert err.value.errors[0].startswith("foxglove.bind: cannot listen on 192.0.2.1:0"), (
            err.value.errors
        )
