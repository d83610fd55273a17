"""Record and replay: every bus event and action of a run in an MCAP file, and the tools
that read it back (docs/RECORDING.md).

- `recorder`: the bus subscriber (event loop side), `writer`: the file thread,
- `codec`: events and actions to JSON and JSON schemas, `foxglove`: Foxglove views,
- `meta`: the file's metadata, `reader`: reading a file with errors that say where,
- `replay`: the recorded inputs through a new brain, compared with the recorded actions.

`RecordingStatus` (the shape /status shows) is defined with the state it is part of,
relayd.runtime.state. `off_status` is here, not in `recorder`: a daemon that does not record never imports the
recorder and its MCAP writer (about 1 MB of resident memory).
"""

from __future__ import annotations

from relayd.runtime.state import RecordingStatus


def off_status() -> RecordingStatus:
    """/status's `recording` when recording is not configured."""
    return {
        "enabled": False,
        "state": "off",
        "path": None,
        "files": 0,
        "bytes": 0,
        "events": 0,
        "dropped": 0,
        "error": None,
    }


__all__ = ["RecordingStatus", "off_status"]
