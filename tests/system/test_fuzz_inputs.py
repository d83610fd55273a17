"""Every command that reads a file, fed crafted files (tests/system/fuzz_inputs.py says
which): none may end in a traceback, and the process's peak resident memory stays bounded.

Each batch runs in a process of its own, so the peak memory measured is the commands' own
(a 3 GB chunk declared in a 10 KB file once took replay past 3 GB). Found on the first
run: a message whose `seq` or `i` was not a number, an event time of 1e308 (an overflow in
the brain), a fleet config that was not UTF-8, TOML nested past the parser's recursion.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
#: The interpreter, relayd, mcap and pydantic take about 90 MB; a decompression bomb or a
#: file read whole into a structure would take far more.
PEAK_RSS_LIMIT_MB = 300

pytestmark = pytest.mark.slow


@pytest.mark.timeout(240)
@pytest.mark.parametrize(
    ("batch", "commands"),
    [
        ("recordings", {"replay": 150, "calibrate": 150}),
        ("toml", {"check-config": 100, "sim --scenario": 30, "fleet -c": 30}),
    ],
)
def test_crafted_files_end_in_an_exit_code_with_bounded_memory(
    batch: str, commands: dict[str, int], tmp_path: Path
) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "tests.system.fuzz_inputs", batch, str(tmp_path)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=220,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["crashes"] == [], "\n".join(result["crashes"][:10])
    for command, at_least in commands.items():
        assert result["counts"][command] >= at_least, result["counts"]
    print(f"{batch}: {result['counts']}, peak RSS {result['peak_rss_mb']:.0f} MB")
    assert result["peak_rss_mb"] < PEAK_RSS_LIMIT_MB
