"""Recordings whose metadata or messages hold the wrong kind of value: `relayd replay` answers
with a clear error and exit 2, or with strict JSON, never with a traceback.

Each case is a good recording rewritten with one thing changed (the mcap library's own
reader and writer), so only that one thing is wrong.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from relayd import cli
from tests.record.test_record import record_route, settings_for

Meta = Callable[[str, dict[str, str]], dict[str, str]]
Msg = Callable[[str, bytes], bytes]


def rewrite(src: Path, dst: Path, meta: Meta | None = None, msg: Msg | None = None) -> Path:
    with src.open("rb") as f_in, dst.open("wb") as f_out:
        reader = make_reader(f_in)
        w = Writer(f_out, compression=CompressionType.ZSTD)
        w.start("relayd", "test")
        for m in reader.iter_metadata():
            w.add_metadata(m.name, meta(m.name, dict(m.metadata)) if meta else dict(m.metadata))
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages():
            assert schema is not None
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id]
                )
            data = msg(channel.topic, message.data) if msg else message.data
            w.add_message(channels[channel.id], message.log_time, data, message.publish_time)
        w.finish()
    return dst


@pytest.fixture
async def recording(tmp_path: Path) -> Path:
    await record_route(settings_for(tmp_path / "r.mcap"), 3.0)
    return tmp_path / "r.mcap"


def _set(name: str, key: str, value: str) -> Meta:
    def change(record: str, data: dict[str, str]) -> dict[str, str]:
        return {**data, key: value} if record == name else data

    return change


@pytest.mark.parametrize(
    ("meta", "expected"),
    [
        (
            _set("relayd", "config", "[1, 2]"),
            "bad relayd metadata (config: a JSON list, not an object)",
        ),
        (_set("relayd", "config", "[" * 50_000 + "]" * 50_000), "config: nested too deeply"),
        (
            _set("recorder", "dropped", "lots"),
            "bad recorder metadata (dropped: 'lots' is not a count)",
        ),
        (_set("recorder", "events", "-3"), "bad recorder metadata (events: '-3' is not a count)"),
    ],
)
async def test_metadata_of_the_wrong_kind_is_exit_2_naming_it(
    recording: Path, meta: Meta, expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = rewrite(recording, recording.with_name("bad.mcap"), meta=meta)
    assert cli.main(["replay", str(bad), "--json"]) == 2
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err, err


async def test_an_event_without_a_time_is_exit_2_not_nan_in_the_json(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A null `t` once came out of replay --json as NaN (not JSON); 1e308 overflowed the brain."""
    for value in (None, 1e308):

        def bad_t(topic: str, data: bytes, value: float | None = value) -> bytes:
            if topic != "/robot/sip":
                return data
            doc = json.loads(data)
            doc["t"] = value
            return json.dumps(doc).encode()

        bad = rewrite(recording, recording.with_name("bad-t.mcap"), msg=bad_t)
        assert cli.main(["replay", str(bad), "--json"]) == 2
        err = capsys.readouterr().err
        assert "/robot/sip message in the chunk does not decode: t:" in err, err
        assert "is not a time of a run" in err


def test_replay_json_is_strict() -> None:
    from relayd.cli.replay import finite

    doc = finite({"t": math.nan, "a": [math.inf, 1.5, {"b": -math.inf}], "c": "x"})
    assert doc == {"t": None, "a": [None, 1.5, {"b": None}], "c": "x"}
    json.dumps(doc, allow_nan=False)


async def test_replay_plots_draw_the_recorded_thresholds(
    recording: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """replay's rssi_bearing.png once had no threshold lines (the simulator's has them)."""
    pytest.importorskip("matplotlib")
    from relayd.cli.replay_plots import plot_recording
    from relayd.record.reader import read_recording
    from relayd.sim import plots

    kept: list = []
    monkeypatch.setattr(plots, "save", lambda fig, path, **kw: kept.append(fig))
    plot_recording(read_recording(recording), recording.parent / "plots")
    rssi = kept[0].axes[0]
    labels = [line.get_label() for line in rssi.get_lines()]
    assert any(lab.startswith("Threshold$_l$ -30") for lab in labels), labels
    assert any(lab.startswith("Threshold$_b$") for lab in labels), labels
    assert len(kept[0].legends) == 1
