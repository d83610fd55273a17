"""Generate many worlds per kind and time it: every seed must give a valid world.

    python -m bench.generate [--seeds 1000] [--kind office] [--workers 2]

Prints, per kind, the seeds tried, the failures (with the seed and error) and the mean
and worst time per world (each measured in the process that generated it), and the
wall time of the whole run. Exit status 1 when any seed fails. `--workers` spreads the
seeds over that many processes (the development machine has two cores; a hall's draws
cost seconds each, its radio's corner graph counted).
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor

from relayd.sim.generate import KINDS, GenerateError, generate


def timed(kind: str, seed: int) -> tuple[float, str | None]:
    """Seconds `generate(kind, seed)` took, and its error if it failed."""
    t0 = time.perf_counter()
    try:
        generate(kind, seed)
        err = None
    except GenerateError as exc:
        err = str(exc)
    return time.perf_counter() - t0, err


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=1000)
    ap.add_argument("--kind", action="append", choices=KINDS, default=None)
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    kinds = args.kind or list(KINDS)
    t_start = time.monotonic()
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = {k: [pool.submit(timed, k, s) for s in range(args.seeds)] for k in kinds}
        bad = 0
        for kind in kinds:
            results = [f.result() for f in futures[kind]]
            times = [t for t, _ in results]
            fails = [f"{seed}: {err}" for seed, (_, err) in enumerate(results) if err]
            bad += len(fails)
            print(
                f"{kind}: {args.seeds} seeds, {len(fails)} failed, "
                f"mean {1000 * sum(times) / len(times):.0f} ms, worst {1000 * max(times):.0f} ms",
                flush=True,
            )
            for line in fails[:20]:
                print(f"  {line}")
    print(f"wall {time.monotonic() - t_start:.0f} s on {args.workers} worker(s)")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
