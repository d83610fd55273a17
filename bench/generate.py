"""Generate many worlds per kind and time it: every seed must give a valid world.

    python -m bench.generate [--seeds 1000] [--kind office]

Prints, per kind, the seeds tried, the failures (with the seed and error) and the mean
and worst time per world. Exit status 1 when any seed fails.
"""

from __future__ import annotations

import argparse
import time

from relayd.sim.generate import KINDS, GenerateError, generate


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=1000)
    ap.add_argument("--kind", action="append", choices=KINDS, default=None)
    args = ap.parse_args()
    bad = 0
    for kind in args.kind or list(KINDS):
        times: list[float] = []
        fails: list[str] = []
        for seed in range(args.seeds):
            t0 = time.perf_counter()
            try:
                generate(kind, seed)
            except GenerateError as exc:
                fails.append(f"{seed}: {exc}")
            times.append(time.perf_counter() - t0)
        bad += len(fails)
        print(
            f"{kind}: {args.seeds} seeds, {len(fails)} failed, "
            f"mean {1000 * sum(times) / len(times):.0f} ms, worst {1000 * max(times):.0f} ms"
        )
        for line in fails[:20]:
            print(f"  {line}")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
