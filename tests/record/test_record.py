"""Recording and replay without devices: the codec, the schemas, the bus hook, the files.

A small in-process route (a Bus, the brain the daemon would build, the Recorder)
is driven with synthetic events on a manual clock, so these tests are fast and exact:
what the recorder wrote is compared with what the brain returned, event by event.
"""

from __future__ import annotations

import asyncio
import errno
import json
import math
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from mcap.records import Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from drivers.airos.model import LinkQuality, Station
from drivers.arcos.sip import Sip
from drivers.wifi.records import RssiSample
from relayd import cli
from relayd.config.load import parse_settings
from relayd.config.model import ConfigError, Settings
from relayd.core.events import (
    Action,
    Decision,
    DeviceEvent,
    DeviceStatus,
    DriveCommand,
    Event,
    LeaderPath,
    LinkEvent,
    LinkModelView,
    LinkSide,
    ModeCommand,
    RearLink,
    RecoveryReport,
    RssiEvent,
    ScanDone,
    ScanPlan,
    ScanReady,
    ScanResult,
    ScanSampleEvent,
    ServoPosition,
    ServoTarget,
    Shutdown,
    SipEvent,
    Tick,
    WheelCommand,
)
from relayd.core.link.model import LinkModelStatus
from relayd.core.recovery.state import Kind, Phase
from relayd.core.recovery.view import RecoveryView
from relayd.core.scan.estimator import ScanEstimate
from relayd.core.vocab import DriveState, Mode, ScanRecord
from relayd.record import codec, writer
from relayd.record.foxglove import VIEWS
from relayd.record.meta import recordable_config, strip_userinfo
from relayd.record.reader import RecordingError, join_parts, read_recording
from relayd.record.recorder import Recorder
from relayd.record.replay import apply_overrides, compare, make_brain, parse_override
from relayd.runtime.bus import Bus
from tests.support import ManualClock, until


def sip(t: float, x_mm: float = 0.0, theta_deg: float = 0.0) -> Sip:
    return Sip(
        t=t,
        x_mm=x_mm,
        y_mm=0.5 * x_mm,
        theta_deg=theta_deg,
        left_mm_s=100.0,
        right_mm_s=120.0,
        battery_v=12.9,
        motors_enabled=True,
        estop=False,
        stall_left=False,
        stall_right=False,
        moving=True,
        sonar=((1, 2500), (6, 3000)),
        bumpers_front=0,
        flags=3,
    )


def quality(t: float, dbm: float = -55.0) -> LinkQuality:
    return LinkQuality(
        t=t,
        signal_dbm=dbm,
        rssi=dbm + 96,
        noise_dbm=-95.0,
        ccq_pct=90.0,
        tx_mbps=54.0,
        rx_mbps=54.0,
        stations=(Station("00:11:22:33:44:55", dbm, 90.0, 54.0, 54.0),),
        mode="ap",
        essid="relay",
        frequency_mhz=2437.0,
        hostname="rear",
    )


def every_type(t: float = 5.0) -> tuple[list[Event], list[Action]]:
    """One instance of every event and action type, with awkward values where it matters."""
    est = ScanEstimate(
        bearing_deg=12.5,
        rssi_leader_dbm=-48.0,
        situation=0,
        angles_deg=(-30.0, 0.0, 30.0),
        rssi_dbm=(-60.0, -48.0, -55.0),
        nrssi_dbm=(-60.0, -48.0, -55.0),
    )
    events: list[Event] = [
        SipEvent(t, sip(t), (None,) * 8 + (2500,) * 8),
        RssiEvent(t, RssiSample(t, None, False)),
        RssiEvent(t, RssiSample(t, -51.25, True)),
        ServoPosition(t, 0, 33.3, True),
        ScanReady(t),
        ScanSampleEvent(t, -30.0, math.nan),  # a non-finite float: null in JSON, NaN back
        ScanDone(t, t - 2.5, 13),
        LinkEvent(t, LinkSide.REAR, quality(t)),
        DeviceEvent(t, "robot", DeviceStatus.UP, "relay1"),
        DeviceEvent(t, "pantilt", DeviceStatus.DOWN),
        ModeCommand(t, Mode.MANUAL),
        DriveCommand(t, 100.0, -100.0),
        Tick(t),
        LeaderPath(t, None, ()),
        LeaderPath(t, (t - 0.1, 1.5, -0.25, 90.0), ((t - 3.0, 0.0, 0.0), (t - 2.0, 0.1, 0.0))),
        Shutdown(t),
    ]
    actions: list[Action] = [
        WheelCommand(0.0, 0.0, True, None),
        WheelCommand(250.5, 300.25, False, t),
        ServoTarget(1, -12.5),
        ScanPlan((-30.0, 0.0, 30.0)),
        Decision(t, 250.5, 300.25, DriveState.DRIVING, "driving", 0, Mode.FOLLOW, True),
        ScanResult(
            ScanRecord(t, (-30.0, 0.0, 30.0), (-60.0, -48.0, -55.0), 12.5, -48.0, 0, 2.5), est
        ),
        RearLink(None),
        RearLink(-61.0),
        RecoveryReport(
            RecoveryView(True, Phase.RETRACE, Kind.LEADER, 2, 14.0, 3.5, 8.0, 60.0, 117, "found")
        ),
        LinkModelView(
            -68.25,
            LinkModelStatus(
                "adaptive",
                -68.25,
                -66.0,
                (-80.0, -50.0),
                10.0,
                0.1,
                True,
                42,
                19.5,
                0.9,
                -73.5,
                1.5,
                0.97,
                -64.0,
                11.4,
                False,
                0,
            ),
        ),
    ]
    return events, actions


def same(a: Any, b: Any) -> bool:
    """Equality where NaN equals NaN (the codec's round trip of a non-finite float)."""
    return json.dumps(codec.to_json(a)) == json.dumps(codec.to_json(b)) and type(a) is type(b)


# -- codec and schemas -------------------------------------------------------------------------


def test_every_event_and_action_round_trips_and_validates_against_its_schema() -> None:
    events, actions = every_type()
    assert {type(e).__name__ for e in events} == set(codec.EVENT_TYPES)
    assert {type(a).__name__ for a in actions} == set(codec.ACTION_TYPES)
    for seq, obj in enumerate([*events, *actions]):
        cls = type(obj)
        i = 0 if cls.__name__ in codec.ACTION_TYPES else None
        doc = json.loads(codec.encode(obj, seq, i))
        jsonschema.Draft202012Validator(codec.message_schema(cls)).validate(doc)
        assert doc.pop("seq") == seq
        doc.pop("i", None)
        back = codec.decode(cls, doc)
        assert same(back, obj), cls.__name__
    sample = next(e for e in events if isinstance(e, ScanSampleEvent))
    nan_back = codec.decode(ScanSampleEvent, json.loads(codec.encode(sample, 0)))
    assert math.isnan(nan_back.rssi_dbm)


def test_schemas_are_strict() -> None:
    """A message with a field too many, too few or of the wrong type fails its schema."""
    schema = codec.message_schema(WheelCommand)
    ok = {"seq": 1, "i": 0, "left_mm_s": 1.0, "right_mm_s": 2.0, "stop": False, "sip_t": None}
    jsonschema.validate(ok, schema)
    for bad in (
        {**ok, "extra": 1},
        {k: v for k, v in ok.items() if k != "stop"},
        {**ok, "stop": "no"},
    ):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, schema)


def test_decode_names_the_bad_field() -> None:
    with pytest.raises(codec.DecodeError, match=r"SipEvent\.sip\.x_mm"):
        doc = codec.to_json(SipEvent(1.0, sip(1.0), ()))
        doc["sip"]["x_mm"] = "far"
        codec.decode(SipEvent, doc)


# -- the bus hook --------------------------------------------------------------------------------


async def test_a_subscriber_with_actions_gets_each_event_with_what_the_brain_returned() -> None:
    bus: Bus[Event, Action] = Bus(lambda ev: [RearLink(-50.0)] if isinstance(ev, Tick) else [])
    plain = bus.subscribe("plain")
    routed = bus.subscribe_with_actions("recorder")
    bus.publish(Tick(1.0))
    bus.publish(Shutdown(2.0))
    assert await plain.get() == Tick(1.0)
    assert await routed.get() == (Tick(1.0), [RearLink(-50.0)])
    assert await routed.get() == (Shutdown(2.0), [])
    bus.unsubscribe(routed)
    bus.publish(Tick(3.0))
    assert routed.get_nowait() is None and len(plain) == 2


# -- a small route: bus + brain + recorder on a manual clock ----------------------------------------


class Route:
    """The daemon's route without devices: what it publishes goes through the real brain."""

    def __init__(self, settings: Settings, clock: ManualClock, **kw: Any) -> None:
        self.settings = settings
        self.clock = clock
        self.brain = make_brain(settings)
        self.bus: Bus[Event, Action] = Bus()
        self.returned: list[tuple[Event, list[Action]]] = []

        def control(ev: Event) -> list[Action]:
            acts = self.brain.handle(ev)
            self.returned.append((ev, acts))
            return acts

        self.bus.connect(control, lambda ev, acts: None)
        self.recorder = Recorder(self.bus, settings, clock, **kw)  # type: ignore[arg-type]

    async def drive(self, seconds: float, start_x: float = 0.0) -> None:
        """10 Hz SIPs and ticks, a rear-link poll a second, a scan every 2.5 s."""
        c = self.clock
        steps = int(seconds * 10)
        if not self.returned:
            self.bus.publish(DeviceEvent(c.t, "robot", DeviceStatus.UP, "relay1"))
            self.bus.publish(DeviceEvent(c.t, "pantilt", DeviceStatus.UP))
        for k in range(steps):
            c.t += 0.1
            self.bus.publish(SipEvent(c.t, sip(c.t, start_x + 10.0 * k, 0.1 * k), (2500,) * 16))
            self.bus.publish(Tick(c.t))
            if k % 10 == 0:
                self.bus.publish(LinkEvent(c.t, LinkSide.REAR, quality(c.t, -50.0 - k % 7)))
            self.bus.publish(RssiEvent(c.t, RssiSample(c.t, -50.0, True)))
            if k % 25 == 0:
                for j, a in enumerate((-30.0, -15.0, 0.0, 15.0, 30.0)):
                    self.bus.publish(ScanSampleEvent(c.t, a, -60.0 + 4 * j - abs(a - 10) / 5))
                self.bus.publish(ScanDone(c.t, c.t - 2.5, 5))
            if k % 5 == 0:
                await asyncio.sleep(0)  # let the recorder's task drain, as the event loop would


def settings_for(path: Path, **record: Any) -> Settings:
    return parse_settings(
        {
            "record": {"enabled": True, "path": str(path), **record},
            "control": {"rear_link": "ignore"},
        }
    )


async def record_route(settings: Settings, seconds: float, **kw: Any) -> Route:
    route = Route(settings, ManualClock(), **kw)
    route.recorder.start()
    task = asyncio.create_task(route.recorder.run())
    await route.drive(seconds)
    await route.recorder.close()
    await asyncio.wait_for(task, 5)
    return route


async def test_the_file_holds_every_event_and_the_actions_the_brain_returned(
    tmp_path: Path,
) -> None:
    route = await record_route(settings_for(tmp_path / "r.mcap"), 12.0)
    rec = read_recording(tmp_path / "r.mcap")
    assert rec.complete and rec.recorder == {
        "events": str(len(route.returned)),
        "actions": str(sum(len(a) for _, a in route.returned)),
        "dropped": "0",
    }
    assert [s.event for s in rec.steps] == [ev for ev, _ in route.returned]
    assert [s.actions for s in rec.steps] == [acts for _, acts in route.returned]
    assert any(
        isinstance(a, WheelCommand) and a.left_mm_s > 0 for s in rec.steps for a in s.actions
    )
    # About one chunk per clock second.
    assert 10 <= rec.chunks <= 14
    # The same brain, fed the recorded inputs, decides exactly the same.
    assert compare(rec, make_brain(settings_for(tmp_path / "r.mcap"))).divergences == 0


def _all_records(path: Path) -> Iterator[Any]:
    with path.open("rb") as f:
        for rec in StreamReader(f, emit_chunks=True).records:
            if isinstance(rec, Chunk):
                yield from breakup_chunk(rec)
            else:
                yield rec


async def test_each_channel_validates_against_the_schema_stored_in_the_file(tmp_path: Path) -> None:
    await record_route(settings_for(tmp_path / "r.mcap"), 6.0)
    schemas: dict[int, dict[str, Any]] = {}
    channels: dict[int, int] = {}
    seen: dict[int, int] = {}
    from mcap.records import Channel

    for rec in _all_records(tmp_path / "r.mcap"):
        if isinstance(rec, Schema):
            assert rec.encoding == "jsonschema"
            schemas[rec.id] = json.loads(rec.data)
            jsonschema.Draft202012Validator.check_schema(schemas[rec.id])
        elif isinstance(rec, Channel):
            assert rec.message_encoding == "json"
            channels[rec.id] = rec.schema_id
        elif isinstance(rec, Message):
            jsonschema.validate(json.loads(rec.data), schemas[channels[rec.channel_id]])
            seen[rec.channel_id] = seen.get(rec.channel_id, 0) + 1
    titles = {schemas[sid]["title"] for sid in channels.values()}
    # The Foxglove views are there, under Foxglove's own schema names.
    assert {"foxglove.PoseInFrame", "foxglove.KeyValuePair", "foxglove.Log"} <= titles
    assert {s["title"] for s in VIEWS.values()} <= titles
    assert all(seen.get(cid, 0) > 0 for cid in channels)


async def test_rotation_makes_parts_that_replay_together(tmp_path: Path) -> None:
    # ~10 KB per clock second here, and ~20 KB of schemas and summary per file: 60 KB parts.
    settings = settings_for(tmp_path, max_file_mb=0.06, max_total_mb=1.0)
    stale = tmp_path / "relayd-20000101T000000Z.mcap"
    stale.write_bytes(b"x" * 950_000)  # an old run's file: deleted to make room for the first part
    keep = tmp_path / "notes.mcap"
    keep.write_bytes(b"x" * 1000)  # not a recording of ours: never deleted
    route = await record_route(settings, 40.0)
    files = route.recorder._sink.files
    assert len(files) >= 3 and not stale.exists() and keep.exists()
    assert all(
        p.stat().st_size < 60_000 + 30_000 for p in files
    )  # + the last chunk and the summary
    parts = [read_recording(p) for p in files]
    assert [p.info.part for p in parts] == list(range(1, len(parts) + 1))
    assert len({p.info.run_id for p in parts}) == 1
    assert compare(join_parts(parts), make_brain(settings)).divergences == 0
    with pytest.raises(RecordingError, match="part 2 of its run"):
        join_parts(parts[1:])


async def test_the_total_size_is_kept_by_deleting_the_oldest_parts(tmp_path: Path) -> None:
    settings = settings_for(tmp_path, max_file_mb=0.06, max_total_mb=0.15)
    route = await record_route(settings, 60.0)
    files = route.recorder._sink.files
    left = sorted(tmp_path.glob("*.mcap"))
    assert len(files) >= 4 and not files[0].exists() and files[-1].exists()
    assert sum(p.stat().st_size for p in left) <= 150_000 + 20_000
    # A run whose first parts are gone cannot be replayed from the start: said so, not guessed.
    with pytest.raises(RecordingError, match=r"is part \d+ of its run"):
        join_parts([read_recording(p) for p in sorted(left, key=lambda p: p.stat().st_mtime)])


def test_directory_mode_names_files_by_start_time(tmp_path: Path) -> None:
    from datetime import UTC, datetime

    series = writer.FileSeries(tmp_path, datetime(2026, 5, 1, 12, 0, 0, tzinfo=UTC))
    assert series.path(1).name == "relayd-20260501T120000Z.mcap"
    assert series.path(2).name == "relayd-20260501T120000Z.2.mcap"
    series.path(1).write_bytes(b"")
    again = writer.FileSeries(tmp_path, datetime(2026, 5, 1, 12, 0, 0, tzinfo=UTC))
    assert again.path(1).name == "relayd-20260501T120000Z-2.mcap"


# -- failures ---------------------------------------------------------------------------------------


class FullDisk:
    """A file that takes `room` bytes, then fails every write with ENOSPC."""

    def __init__(self, path: Path, room: int) -> None:
        self._f = path.open("wb")
        self.room = room

    def write(self, data: bytes) -> int:
        if self._f.tell() + len(data) > self.room:
            raise OSError(errno.ENOSPC, "No space left on device")
        return self._f.write(data)

    def tell(self) -> int:
        return self._f.tell()

    def flush(self) -> None:
        self._f.flush()

    def close(self) -> None:
        self._f.close()


async def test_a_write_error_stops_the_recording_once_and_the_route_goes_on(tmp_path: Path) -> None:
    from structlog.testing import capture_logs

    settings = settings_for(tmp_path / "r.mcap")
    route = Route(settings, ManualClock(), opener=lambda p: FullDisk(p, 20_000))
    route.recorder.start()
    task = asyncio.create_task(route.recorder.run())
    with capture_logs() as logs:
        await route.drive(8.0)
        await until(lambda: route.recorder.state == "failed", "the recorder to fail", 10)
        before = len(route.returned)
        await route.drive(3.0)
        await route.recorder.close()
    await asyncio.wait_for(task, 5)
    warnings = [e for e in logs if e["event"] == "recording_stopped"]
    assert len(warnings) == 1 and "No space left" in warnings[0]["error"]
    status = route.recorder.status()
    assert status["state"] == "failed" and "No space left" in status["error"]
    # The brain kept deciding after the failure, and nothing queues for the recorder any more.
    assert len(route.returned) > before + 50
    assert route.bus._routed == [] and route.recorder._sub.closed
    # What was written before the disk filled reads, up to its last complete chunk.
    with pytest.raises(RecordingError, match="without its summary"):
        read_recording(tmp_path / "r.mcap")
    part = read_recording(tmp_path / "r.mcap", partial=True)
    assert part.steps and not part.complete


class StalledDisk(FullDisk):
    """A file whose writes block (a hung disk) until `release` is set."""

    def __init__(self, path: Path, release: threading.Event) -> None:
        super().__init__(path, 1 << 30)
        self.release = release
        self.stuck = threading.Event()
        #: time.monotonic() when the first write hung.
        self.stuck_t = 0.0

    def write(self, data: bytes) -> int:
        if not self.stuck.is_set():
            self.stuck_t = time.monotonic()
            self.stuck.set()
        self.release.wait(30)
        return super().write(data)


async def test_a_stalled_disk_ends_the_recording_instead_of_growing_memory(tmp_path: Path) -> None:
    release = threading.Event()
    disks: list[StalledDisk] = []

    def opener(p: Path) -> StalledDisk:
        disks.append(StalledDisk(p, release))
        return disks[-1]

    stall_s = 0.2
    route = Route(settings_for(tmp_path / "r.mcap"), ManualClock(), opener=opener, stall_s=stall_s)
    route.recorder.start()
    task = asyncio.create_task(route.recorder.run())
    try:
        await route.drive(2.0)
        # The writer thread is inside a hung write (on a busy machine it may start late),
        # and stays there past stall_s of wall time.
        await until(lambda: bool(disks) and disks[0].stuck.is_set(), "the writer to hang", 10)
        # The recorder judges a stall by wall time (a real disk hangs in real time): the
        # hung write must have lasted past stall_s before more data arrives.
        await until(
            lambda: time.monotonic() - disks[0].stuck_t > stall_s, "the write hung past stall_s", 10
        )
        await route.drive(2.0)
        await until(lambda: route.recorder.state == "failed", "the recorder to give up", 10)
        assert "not keeping up" in (route.recorder.error or "")
    finally:
        release.set()
        await route.recorder.close()
        await asyncio.wait_for(task, 5)
    assert route.recorder.state == "failed"


# -- metadata and secrets ---------------------------------------------------------------------------


def test_no_secret_in_the_recorded_config() -> None:
    assert strip_userinfo("http://ubnt:hunter2@10.0.0.2:80/x") == "http://10.0.0.2:80/x"
    settings = parse_settings(
        {
            "ap": {
                "rear": {
                    "url": "https://ubnt:hunter2@10.0.0.2",
                    "password_file": "/tmp/relayd-test-ap-pass",
                }
            }
        }
    )
    doc = json.dumps(recordable_config(settings))
    assert "hunter2" not in doc and "10.0.0.2" in doc and "/tmp/relayd-test-ap-pass" in doc


async def test_metadata_carries_version_config_and_start(tmp_path: Path) -> None:
    settings = settings_for(tmp_path / "r.mcap")
    await record_route(settings, 1.0)
    meta = {
        r.name: r.metadata for r in _all_records(tmp_path / "r.mcap") if isinstance(r, Metadata)
    }
    from relayd import __version__

    assert meta["relayd"]["version"] == __version__
    assert parse_settings(json.loads(meta["relayd"]["config"])) == settings
    assert (
        meta["relayd"]["start_time"].startswith("20") and int(meta["relayd"]["start_unix_ns"]) > 0
    )


# -- config --------------------------------------------------------------------------------------


def test_record_section_is_strict() -> None:
    assert Settings().record.enabled is False
    with pytest.raises(ConfigError, match=r"record\.max_file"):
        parse_settings({"record": {"max_file": 10}})
    with pytest.raises(ConfigError, match="max_total_mb must be at least max_file_mb"):
        parse_settings({"record": {"max_file_mb": 100, "max_total_mb": 50}})


# -- replay and what-if -------------------------------------------------------------------------


def test_overrides_parse_toml_values_and_refuse_unknown_keys() -> None:
    assert parse_override("control.kp=2.0") == ("control.kp", 2.0)
    assert parse_override("control.rear_link=ignore") == ("control.rear_link", "ignore")
    base = parse_settings({"control": {"rear_link": "ignore"}}).model_dump(mode="json")
    assert apply_overrides(base, [("control.kp", 2.5)]).control.kp == 2.5
    from relayd.record.replay import OverrideError

    with pytest.raises(OverrideError, match="no key 'kpp'"):
        apply_overrides(base, [("control.kpp", 2.0)])
    with pytest.raises(OverrideError, match=r"control\.kp"):
        apply_overrides(base, [("control.kp", -1.0)])


async def test_replay_cli_zero_divergences_what_if_and_plots(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    await record_route(settings_for(tmp_path / "r.mcap"), 8.0)
    f = str(tmp_path / "r.mcap")
    assert cli.main(["replay", f, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["divergences"] == 0 and out["first_divergence"] is None
    assert out["events"] > 100 and out["actions"] > 100 and out["file"] == f
    # What-if: another kp changes the wheel speeds; that is a report, not a failure.
    assert (
        cli.main(
            ["replay", f, "--json", "--set", "control.kp=3.0", "--plot", str(tmp_path / "plots")]
        )
        == 0
    )
    w = json.loads(capsys.readouterr().out)["what_if"]
    assert w["differences"] > 0 and w["first_t"] is not None and w["max_wheel_diff_mm_s"] > 1.0
    assert (tmp_path / "plots" / "rssi_bearing.png").stat().st_size > 1000
    assert (tmp_path / "plots" / "path.png").stat().st_size > 1000


async def test_a_changed_recording_diverges_with_exit_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Replay is a real comparison: a brain configured differently from the recording diverges."""
    settings = settings_for(tmp_path / "r.mcap")
    await record_route(settings, 5.0)
    rec = read_recording(tmp_path / "r.mcap")
    # kp doubled doubles every turn; a kd change alone moves this route's slowly turning
    # bearing by less than RVEL's 1 deg/s step with the lobe fit, so nothing the robot gets.
    other = compare(rec, make_brain(apply_overrides(rec.info.config, [("control.kp", 2.0)])))
    assert other.divergences > 0 and other.first is not None
    assert other.first["recorded"] != other.first["replayed"]


async def test_another_version_is_refused_naming_both(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    await record_route(settings_for(tmp_path / "r.mcap"), 2.0)
    import relayd.cli.replay as replay_cmd

    monkeypatch.setattr(replay_cmd, "__version__", "9.9.9")
    assert cli.main(["replay", str(tmp_path / "r.mcap")]) == 2
    err = capsys.readouterr().err
    assert "relayd 0.1.0" in err and "relayd 9.9.9" in err
    assert cli.main(["replay", str(tmp_path / "r.mcap"), "--any-version", "--json"]) == 0


async def test_a_corrupt_or_cut_file_gives_exit_2_naming_where(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    await record_route(settings_for(tmp_path / "r.mcap"), 5.0)
    good = (tmp_path / "r.mcap").read_bytes()
    rec = read_recording(tmp_path / "r.mcap")
    assert rec.chunks >= 4
    # Damage the middle of the third chunk.
    offsets = [off for off, r in _chunk_offsets(tmp_path / "r.mcap")]
    bad = bytearray(good)
    mid = offsets[2] + 80
    bad[mid : mid + 16] = bytes(16)
    (tmp_path / "corrupt.mcap").write_bytes(bytes(bad))
    assert cli.main(["replay", str(tmp_path / "corrupt.mcap")]) == 2
    err = capsys.readouterr().err
    assert f"at byte {offsets[2]}" in err and "chunk 3 is corrupt" in err
    # Cut in the middle of a chunk: the reader names where the file ends.
    (tmp_path / "cut.mcap").write_bytes(good[: offsets[3] + 50])
    assert cli.main(["replay", str(tmp_path / "cut.mcap")]) == 2
    err = capsys.readouterr().err
    assert (
        f"at byte {offsets[3]}" in err
        and "ends without its summary" in err
        and "3 complete chunk(s)" in err
    )
    # ... and --partial replays what it holds.
    assert cli.main(["replay", str(tmp_path / "cut.mcap"), "--partial", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["complete"] is False
    (tmp_path / "junk.mcap").write_bytes(b"not a recording at all")
    assert cli.main(["replay", str(tmp_path / "junk.mcap")]) == 2
    assert "not an MCAP file" in capsys.readouterr().err


def _chunk_offsets(path: Path) -> list[tuple[int, Chunk]]:
    out = []
    with path.open("rb") as f:
        reader = StreamReader(f, emit_chunks=True)
        start = f.tell()
        for rec in reader.records:
            if isinstance(rec, Chunk):
                out.append((start, rec))
            start = f.tell()
    return out


def test_the_example_config_records_where_the_service_may_write() -> None:
    """ProtectSystem=strict leaves only the StateDirectory writable: the recordings go there."""
    import tomllib

    root = Path(__file__).resolve().parents[2]
    config = tomllib.loads((root / "config" / "relayd.toml").read_text())
    unit = (root / "systemd" / "relayd.service").read_text()
    state_dir = next(
        line.split("=", 1)[1].strip()
        for line in unit.splitlines()
        if line.startswith("StateDirectory=")
    )
    assert config["record"]["enabled"] is True
    assert config["record"]["path"].startswith(f"/var/lib/{state_dir}/")
    parse_settings(config)  # and it validates


def test_recording_md_lists_every_channel() -> None:
    doc = (Path(__file__).resolve().parents[2] / "docs" / "RECORDING.md").read_text()
    for cls in [*codec.EVENT_TYPES.values(), *codec.ACTION_TYPES.values()]:
        assert f"| `{codec.topic_of(cls)}` | `{codec.schema_name(cls)}` |" in doc, cls.__name__
    for topic, schema in VIEWS.items():
        assert f"| `{topic}` | `{schema['title']}` |" in doc, topic


def test_relayd_status_shows_the_recording() -> None:
    from relayd.cli.status import format_status

    base = {"mode": "follow", "state": "driving", "reason": "driving"}
    ok = {
        "enabled": True,
        "state": "recording",
        "path": "/var/lib/relayd/recordings/r.mcap",
        "files": 1,
        "bytes": 2_500_000,
        "events": 10,
        "dropped": 0,
        "error": None,
    }
    line = next(
        x
        for x in format_status({**base, "recording": ok}).splitlines()
        if x.startswith("recording")
    )
    assert line.split() == [
        "recording",
        "recording",
        "/var/lib/relayd/recordings/r.mcap",
        "2.5",
        "MB",
    ]
    failed = format_status(
        {**base, "recording": {**ok, "state": "failed", "error": "OSError: disk full"}}
    )
    assert "FAILED" in failed and "DISK FULL" in failed
    assert "recording" not in format_status({**base, "recording": None}).replace("reason", "")


async def test_a_recorder_never_started_closes_cleanly(tmp_path: Path) -> None:
    """The daemon can fail before its devices start (a taken API port): shutdown still closes it."""
    route = Route(settings_for(tmp_path / "r.mcap"), ManualClock())
    await route.recorder.close()
    assert route.recorder.state == "stopped" and route.bus._routed == []
    assert not (tmp_path / "r.mcap").exists()


def test_the_record_benchmark_measures_something() -> None:
    """bench/record.py's load-independent parts, short: the loop cost and the size of a sim's files."""
    from bench import record as bench_record

    median_us, p99_us = asyncio.run(bench_record._loop_cost(400))
    assert 0.5 < median_us < 5000 and p99_us >= median_us
    size, sim_s, relays = bench_record._sim_size(15.0)
    assert relays == 2 and 10.0 <= sim_s <= 15.5
    per_hour_mb = size / relays / sim_s * 3600 / 1e6
    assert 1.0 < per_hour_mb < 200.0
