"""Crafted files for every command that reads one, and a harness that feeds them in.

    python -m tests.system.fuzz_inputs recordings|toml DIR     # prints one JSON document

Run in a process of its own (tests/system/test_fuzz_inputs.py) so its peak resident
memory is the commands' own. The files, each from a good one:

- truncated at ten places, and with single bits flipped at twenty seeded places;
- every key (two levels deep) of each channel's first message (recordings), or every key
  of every table (TOML files), set to a value of the wrong kind, one file per key;
- nesting deeper than any parser recurses (a TOML array, a recorded config, a message);
- sizes declared far beyond the file (an MCAP chunk of 3 GB, a record of 2^62 bytes).

The commands: `relayd replay`, `relayd calibrate path-loss --from`, `relayd check-config`,
`relayd sim --scenario` (its loader: a scenario that loads would start a simulation) and
`relayd fleet -c` (its settings: a fleet that loads would start serving). An outcome is an
exit code, or a crash: any exception, with the file and the last lines of its traceback.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import json
import random
import resource
import struct
import sys
import tomllib
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from relayd.config.tomlwriter import dump_toml

REPO = Path(__file__).resolve().parents[2]
#: Values of the wrong kind, drawn in turn for each key.
WRONG = [None, "lots", -1, 1e308, True, [1, 2], {"a": 1}, "", 0, [], float("nan")]
WRONG_TOML = ["lots", -1, 1e308, True, [1, 2], {"a": 1}, "", 0, [], float("inf")]


# -- mutations of bytes ------------------------------------------------------------------


def truncations(data: bytes) -> Iterator[tuple[str, bytes]]:
    for k in range(1, 11):
        cut = len(data) * k // 11
        yield f"cut{cut}", data[:cut]


def bit_flips(data: bytes, seed: int = 1) -> Iterator[tuple[str, bytes]]:
    rng = random.Random(seed)
    for _ in range(20):
        at = rng.randrange(len(data))
        flipped = bytearray(data)
        flipped[at] ^= 1 << rng.randrange(8)
        yield f"flip{at}", bytes(flipped)


# -- TOML --------------------------------------------------------------------------------


def leaf_paths(node: Any, path: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    if isinstance(node, dict):
        for key, value in node.items():
            yield from leaf_paths(value, (*path, key))
    elif isinstance(node, list) and node and all(isinstance(v, dict) for v in node):
        for i, value in enumerate(node):
            yield from leaf_paths(value, (*path, i))
    else:
        yield path


def replaced(doc: Any, path: tuple[Any, ...], value: Any) -> Any:
    if not path:
        return value
    head, rest = path[0], path[1:]
    if isinstance(doc, dict):
        return {k: replaced(v, rest, value) if k == head else v for k, v in doc.items()}
    return [replaced(v, rest, value) if i == head else v for i, v in enumerate(doc)]


def toml_variants(text: str) -> Iterator[tuple[str, bytes]]:
    data = text.encode()
    yield from truncations(data)
    yield from bit_flips(data)
    doc = tomllib.loads(text)
    for n, path in enumerate(leaf_paths(doc)):
        wrong = WRONG_TOML[n % len(WRONG_TOML)]
        try:
            text_out = dump_toml(replaced(doc, path, wrong))
        except (AttributeError, TypeError, ValueError):
            continue  # a shape the writer cannot express as TOML: no such file can exist
        yield "type-" + ".".join(map(str, path)), text_out.encode()
    yield "deep-array", b"a = " + b"[" * 50_000 + b"]" * 50_000 + b"\n"
    yield "deep-table", b"a = " + b"{b = " * 50_000 + b"1" + b"}" * 50_000 + b"\n"
    yield "long-line", b'x = "' + b"a" * (8 << 20) + b'"\n'


# -- recordings --------------------------------------------------------------------------

Meta = Callable[[str, dict[str, str]], dict[str, str]]
Msg = Callable[[str, int, bytes], bytes]


def rewrite(src: bytes, meta: Meta | None = None, msg: Msg | None = None) -> bytes:
    out = io.BytesIO()
    reader = make_reader(io.BytesIO(src))
    w = Writer(out, compression=CompressionType.ZSTD)
    w.start("relayd", "fuzz")
    for m in reader.iter_metadata():
        w.add_metadata(m.name, meta(m.name, dict(m.metadata)) if meta else dict(m.metadata))
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    for i, (schema, channel, message) in enumerate(reader.iter_messages()):
        assert schema is not None
        if schema.id not in schemas:
            schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
        if channel.id not in channels:
            channels[channel.id] = w.register_channel(
                channel.topic, channel.message_encoding, schemas[schema.id]
            )
        data = msg(channel.topic, i, message.data) if msg else message.data
        w.add_message(channels[channel.id], message.log_time, data, message.publish_time)
    w.finish()  # type: ignore[no-untyped-call]
    return out.getvalue()


def first_messages(src: bytes) -> dict[str, tuple[int, dict[str, Any]]]:
    """Each topic's first message: its index in the file and its JSON document."""
    out: dict[str, tuple[int, dict[str, Any]]] = {}
    for i, (_s, channel, message) in enumerate(make_reader(io.BytesIO(src)).iter_messages()):
        if channel.topic not in out:
            out[channel.topic] = (i, json.loads(message.data))
    return out


def _json_leaves(
    node: Any, path: tuple[Any, ...] = (), depth: int = 0
) -> Iterator[tuple[Any, ...]]:
    if path:
        yield path
    if isinstance(node, dict) and depth < 2:
        for key, value in node.items():
            yield from _json_leaves(value, (*path, key), depth + 1)


def recording_variants(src: bytes) -> Iterator[tuple[str, bytes]]:
    yield from truncations(src)
    yield from bit_flips(src)
    n = 0
    for topic, (index, doc) in first_messages(src).items():
        for path in _json_leaves(doc):
            wrong = WRONG[n % len(WRONG)]
            n += 1
            body = json.dumps(replaced(doc, path, wrong)).encode()

            def msg(t: str, i: int, data: bytes, at: int = index, body: bytes = body) -> bytes:
                return body if i == at else data

            yield (
                f"type{topic.replace('/', '_')}-" + ".".join(map(str, path)),
                rewrite(src, msg=msg),
            )
    deep = b'{"a":' * 50_000 + b"1" + b"}" * 50_000
    for topic, (index, _doc) in first_messages(src).items():
        if topic in ("/link", "/robot/sip"):
            yield (
                f"deep{topic.replace('/', '_')}",
                rewrite(src, msg=lambda t, i, d, at=index: deep if i == at else d),
            )
    for name, key, value in (
        ("relayd", "config", "[" * 50_000 + "]" * 50_000),
        ("relayd", "config", "[1, 2]"),
        ("relayd", "clock_t0", "soon"),
        ("recorder", "dropped", "lots"),
        ("robot", "name", "\x00" * 100),
    ):
        yield (
            f"meta-{name}-{key}",
            rewrite(src, meta=lambda r, d, n=name, k=key, v=value: {**d, k: v} if r == n else d),
        )
    yield "chunk-3GB", declared_chunk(src, 3 << 30)
    yield "record-2^62", declared_record(src, 1 << 62)


def _first_chunk(data: bytes) -> int:
    i = 8
    while i < len(data):
        opcode, length = data[i], struct.unpack_from("<Q", data, i + 1)[0]
        if opcode == 0x06:
            return i
        i += 9 + length
    raise ValueError("no chunk")


def declared_chunk(data: bytes, size: int) -> bytes:
    out = bytearray(data)
    struct.pack_into("<Q", out, _first_chunk(data) + 9 + 16, size)
    return bytes(out)


def declared_record(data: bytes, size: int) -> bytes:
    out = bytearray(data)
    struct.pack_into("<Q", out, _first_chunk(data) + 1, size)
    return bytes(out)


# -- the harness -------------------------------------------------------------------------


def _outcome(call: Callable[[], Any]) -> str | None:
    """None for an exit (any code), else the crash: the exception and where it came from."""
    sink = io.StringIO()
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            call()
    except SystemExit:
        return None
    except Exception as exc:  # a crash is what this harness reports
        tb = traceback.format_exception(exc)
        return f"{type(exc).__name__}: {str(exc)[:200]} | {''.join(tb[-3:])[-600:]}"
    return None


def good_recording(tmp: Path) -> bytes:
    from tests.record.test_record import record_route, settings_for

    asyncio.run(record_route(settings_for(tmp / "good.mcap"), 1.5))
    return (tmp / "good.mcap").read_bytes()


def run(which: str, tmp: Path) -> dict[str, Any]:
    from relayd.cli import main
    from relayd.cli.fleet import settings_from_args
    from relayd.config.model import ConfigError
    from relayd.sim.scenario import ScenarioError, load_scenario

    crashes: list[str] = []
    counts: dict[str, int] = {}

    def feed(kind: str, name: str, data: bytes, suffix: str, call: Callable[[Path], Any]) -> None:
        path = tmp / f"{kind}-{name}{suffix}"
        path.write_bytes(data)
        crash = _outcome(lambda: call(path))
        counts[kind] = counts.get(kind, 0) + 1
        if crash is not None:
            crashes.append(f"{kind} {name}: {crash}")
        path.unlink()

    def quiet(*errors: type[Exception]) -> Callable[[Callable[[Path], Any]], Callable[[Path], Any]]:
        def wrap(fn: Callable[[Path], Any]) -> Callable[[Path], Any]:
            def call(path: Path) -> Any:
                try:
                    return fn(path)
                except errors:
                    return None

            return call

        return wrap

    if which == "recordings":
        for name, data in recording_variants(good_recording(tmp)):
            feed("replay", name, data, ".mcap", lambda p: main(["replay", str(p), "--json"]))
            feed(
                "calibrate",
                name,
                data,
                ".mcap",
                lambda p: main(
                    ["calibrate", "path-loss", "--from", str(p), "--out", str(tmp / "cal")]
                ),
            )
        return _result(crashes, counts)
    config = (REPO / "config" / "relayd.toml").read_text()
    for name, data in toml_variants(config):
        feed("check-config", name, data, ".toml", lambda p: main(["check-config", str(p)]))
    scenario = (REPO / "relayd" / "sim" / "scenarios" / "corridor.toml").read_text()
    for name, data in toml_variants(scenario):
        feed("sim --scenario", name, data, ".toml", quiet(ScenarioError)(load_scenario))
    fleet = (
        '[fleet]\nbind = "127.0.0.1"\nport = 8090\nallowed_hosts = ["cc.lab"]\n'
        '[[fleet.relay]]\nname = "relay1"\nurl = "http://192.168.1.31:8080"\n'
        'token_env = "RELAY1_TOKEN"\norigin = [0.0, 0.0, 0.0]\n'
        '[[fleet.relay]]\nname = "relay2"\nurl = "http://192.168.1.32:8080"\n'
    )

    def fleet_settings(p: Path) -> Any:
        ns = argparse.Namespace(
            config=str(p),
            relay=[],
            token_file=None,
            bind=None,
            port=None,
            poll_s=None,
            timeout_s=None,
            allowed_host=[],
        )
        return settings_from_args(ns)

    for name, data in toml_variants(fleet):
        feed("fleet -c", name, data, ".toml", quiet(ConfigError)(fleet_settings))
    return _result(crashes, counts)


def _result(crashes: list[str], counts: dict[str, int]) -> dict[str, Any]:
    return {
        "crashes": crashes,
        "counts": counts,
        "peak_rss_mb": _peak_rss_mb(),
    }


def _peak_rss_mb() -> float:
    """This process's own peak resident memory (VmHWM, MB).

    Not getrusage's ru_maxrss: Linux carries that over fork and exec, so a child of a
    test worker that had grown to 300 MB reported 300 MB whatever it used itself.
    VmHWM belongs to the address space, which exec makes anew.
    """
    with open("/proc/self/status", encoding="ascii") as status:
        for line in status:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # not Linux


if __name__ == "__main__":
    sys.setrecursionlimit(1000)
    print(json.dumps(run(sys.argv[1], Path(sys.argv[2]))))
