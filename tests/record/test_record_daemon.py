"""Recording with real daemons: the simulator, a killed `relayd run`, a full disk.

- The simulator (virtual time, in-process devices) records each relay through that
  relay's own daemon; the recording replays with zero divergences and every message
  validates against the schema stored with its channel.
- `relayd run --record` in a subprocess on the fake rig, killed with SIGKILL: the file
  reads (the `mcap` library's own reader, and `relayd replay --partial`) up to its
  last complete chunk, and holds neither the AP password nor the API token.
- A disk that fills up mid-run (an injected writer error, and a real tmpfs when this
  runs as root) stops the recording with one warning and a /status flag while the
  robot goes on driving.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import subprocess
import sys
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from drivers.arcos.codec import Command
from relayd import cli
from relayd.config.load import parse_settings
from relayd.core.events import ScanResult, Shutdown, WheelCommand
from relayd.core.vocab import DriveState
from relayd.daemon import Daemon
from relayd.fakes.rig import FakeRig
from relayd.record import writer
from relayd.record.reader import RecordingError, read_recording
from relayd.runtime.vtime import LoopClock
from tests.record.test_record import FullDisk
from tests.support import running, until

pytestmark = pytest.mark.slow

SCAN = {"samples": 9, "width_deg": 120, "settle_s": 0.02}
PANTILT = {"speed_deg_s": 1000}


def contents(path: Path) -> Iterator[Any]:
    """Every record of a file with the chunks opened (read what a tool would see)."""
    with path.open("rb") as f:
        try:
            for rec in StreamReader(f, emit_chunks=True).records:
                if isinstance(rec, Chunk):
                    yield from breakup_chunk(rec)
                else:
                    yield rec
        except (McapError, EOFError, ValueError):
            return  # a cut file: what was there has been seen


def validate_channels(path: Path) -> dict[str, int]:
    """Every message against its channel's stored JSON schema; message counts by topic."""
    schemas: dict[int, Any] = {}
    channels: dict[int, tuple[str, int]] = {}
    counts: dict[str, int] = {}
    for rec in contents(path):
        if isinstance(rec, Schema):
            schemas[rec.id] = jsonschema.Draft202012Validator(json.loads(rec.data))
        elif isinstance(rec, Channel):
            channels[rec.id] = (rec.topic, rec.schema_id)
        elif isinstance(rec, Message):
            topic, sid = channels[rec.channel_id]
            schemas[sid].validate(json.loads(rec.data))
            counts[topic] = counts.get(topic, 0) + 1
    return counts


def test_a_simulated_run_recorded_then_replayed_has_zero_divergences(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sim"
    # The shortest run with scans and driving: the obstacle course, 15 s, one relay.
    assert (
        cli.main(
            [
                "sim",
                "--scenario",
                "obstacle",
                "--seconds",
                "15",
                "--speed",
                "max",
                "--record",
                "--no-plots",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    capsys.readouterr()
    f = out / "relay1.mcap"
    rec = read_recording(f)
    assert rec.complete and rec.robot is not None and rec.robot["name"] == "relay1"
    assert rec.recorder is not None and rec.recorder["dropped"] == "0"
    actions = [a for s in rec.steps for a in s.actions]
    assert sum(isinstance(a, ScanResult) for a in actions) >= 3
    assert any(
        isinstance(a, WheelCommand) and a.left_mm_s > 0 and a.right_mm_s > 0 for a in actions
    )
    assert 12 <= rec.chunks <= 20  # about one chunk per simulated second
    # A normal stop: the last event is the shutdown, and the file has its summary, so the
    # mcap library's indexed reader (what viewers use to seek) finds every message.
    assert isinstance(rec.steps[-1].event, Shutdown)
    with f.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert len(summary.chunk_indexes) == rec.chunks
        assert sum(1 for _ in reader.iter_messages()) == summary.statistics.message_count
    counts = validate_channels(f)
    assert {
        "/robot/sip",
        "/robot/pose",
        "/wifi/rssi",
        "/scan/sample",
        "/action/wheels",
        "/action/decision",
        "/state",
        "/log",
    } <= set(counts)
    assert cli.main(["replay", str(f), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["divergences"] == 0 and report["first_divergence"] is None
    assert report["events"] == len(rec.steps) and report["actions"] == len(actions)
    # What-if: a stiffer heading gain turns the wheels differently; a report, exit 0.
    assert cli.main(["replay", str(f), "--json", "--set", "control.kp=2.0"]) == 0
    what_if = json.loads(capsys.readouterr().out)["what_if"]
    assert what_if["differences"] > 0 and what_if["max_wheel_diff_mm_s"] > 1.0
    assert what_if["first_t"] is not None and what_if["max_bearing_diff_deg"] == 0.0


@contextlib.asynccontextmanager
async def relay(tmp_path: Path, **record: Any) -> AsyncIterator[tuple[FakeRig, Daemon]]:
    """A daemon recording on the rig's in-memory devices, on virtual time."""
    rig = FakeRig(tmp_path, leader_xy_m=(6.0, 1.0), clock=LoopClock(), links="memory")
    async with rig:
        doc = rig.config_doc(scan=SCAN, pantilt=PANTILT)
        doc["record"] = {"enabled": True, **record}
        daemon = Daemon(parse_settings(doc), env=rig.env, clock=rig.clock)
        async with running(daemon):
            yield rig, daemon


def forward_commands(rig: FakeRig) -> int:
    return sum(
        1
        for cmd, arg in rig.robot.commands
        if cmd == Command.VEL and isinstance(arg, int) and arg > 0
    )


async def drives_on_after_the_recording_failed(rig: FakeRig, daemon: Daemon) -> None:
    st = daemon.state
    await until(
        lambda: st.snapshot(daemon.clock.now())["recording"]["state"] == "failed",
        "the recording to fail",
        30,
    )
    rec = st.snapshot(daemon.clock.now())["recording"]
    assert "No space left" in rec["error"] or "ENOSPC" in rec["error"] or "28" in rec["error"]
    sent, x = forward_commands(rig), rig.robot.x_mm
    scans = st.scan_count
    await until(
        lambda: (
            forward_commands(rig) > sent + 3
            and rig.robot.x_mm > x + 50
            and st.scan_count > scans + 1
        ),
        "the robot driving and scanning on",
        30,
    )
    assert st.state is DriveState.DRIVING


@pytest.mark.virtual_time
async def test_a_full_disk_stops_the_recording_and_the_robot_keeps_driving(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from structlog.testing import capture_logs

    monkeypatch.setattr(writer, "open_file", lambda p: FullDisk(p, 40_000))
    with capture_logs() as logs:
        async with relay(tmp_path, path=str(tmp_path / "rec.mcap")) as (rig, daemon):
            await until(lambda: forward_commands(rig) > 0, "the relay driving", 30)
            await drives_on_after_the_recording_failed(rig, daemon)
    assert [e["event"] for e in logs].count("recording_stopped") == 1
    part = read_recording(tmp_path / "rec.mcap", partial=True)
    assert part.steps and not part.complete


@pytest.mark.virtual_time
async def test_a_real_full_tmpfs(tmp_path: Path) -> None:
    """The same with a file system that really fills up (root only: mounts a 96 KB tmpfs)."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=96k", "tmpfs", str(mnt)],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        async with relay(tmp_path, path=str(mnt)) as (rig, daemon):
            await until(lambda: forward_commands(rig) > 0, "the relay driving", 30)
            await drives_on_after_the_recording_failed(rig, daemon)
        files = list(mnt.glob("relayd-*.mcap"))
        assert len(files) == 1
        assert read_recording(files[0], partial=True).steps
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


async def test_a_killed_daemon_leaves_a_file_that_reads_to_its_last_chunk(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec_path = tmp_path / "killed.mcap"
    async with FakeRig(tmp_path, leader_xy_m=(6.0, 1.0)) as rig:
        cfg = rig.write_config(secrets_in_files=True, scan=SCAN, pantilt=PANTILT)
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "relayd",
            "run",
            "-c",
            str(cfg),
            "--record",
            str(rec_path),
            "--log-format",
            "json",
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:

            def chunks() -> int:
                try:
                    return read_recording(rec_path, partial=True).chunks if rec_path.exists() else 0
                except RecordingError:
                    return 0  # not even its metadata yet

            await until(
                lambda: chunks() >= 3 and forward_commands(rig) > 0, "three chunks written", 60
            )
        finally:
            proc.send_signal(signal.SIGKILL)
            await proc.wait()
    assert proc.returncode == -signal.SIGKILL
    # The mcap library's own reader reads it in file order, up to where it ends (sorting by
    # log time would need the whole file first).
    messages = 0
    with rec_path.open("rb") as f, contextlib.suppress(McapError):
        for _ in NonSeekingReader(f).iter_messages(log_time_order=False):
            messages += 1
    assert messages > 100
    # relayd replay says where it ends, and replays what it holds with --partial.
    assert cli.main(["replay", str(rec_path)]) == 2
    assert "ends without its summary" in capsys.readouterr().err
    assert cli.main(["replay", str(rec_path), "--partial", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["complete"] is False and report["divergences"] == 0 and report["events"] > 50
    # No secret in it: the run resolved both from files, neither reached the recording.
    blob = b"".join(
        r.data
        if isinstance(r, Message | Schema)
        else json.dumps(r.metadata).encode()
        if isinstance(r, Metadata)
        else b""
        for r in contents(rec_path)
    )
    config = read_recording(rec_path, partial=True).info.config
    assert config["ap"]["rear"]["password_file"].endswith("relay1-ap-password")  # where, not what
    assert rig.ap_password.encode() not in blob and rig.api_token.encode() not in blob
    assert rig.ap_password.encode() not in rec_path.read_bytes()
