"""The corridor without relays on the link budget alone, under both radio models.

    python -m bench.cornerpath [--scenario corridor] [--set office=13]

Walks the scenario's person from the command center with no relays and no daemons (the
link budget only, shadowing on, no fading) and prints, per radio model, the end-to-end
throughput at the times that matter to the paper's fig. 6-17: before the first corner,
just round it, before and after the second, at the goal. Then the radio's own cost: the
CPU time of the link queries a simulated second of a two-relay convoy makes (20 ticks,
three hops, each asked for its budget and its Yagi sample), per model, on a generated
office and on the corridor. `--set MATERIAL=DB` overrides a wall loss (what-if runs).
"""

from __future__ import annotations

import argparse
import time

from relayd.sim.scenario import Scenario, load_scenario
from relayd.sim.world import World

MODELS = ("wall-count", "dominant-path")
TIMES_S = (20, 60, 80, 90, 100, 120, 170, 190, 200, 240, 280, 294)


def _variant(
    sc: Scenario, model: str, losses: dict[str, float], relays: int, turn_db: float | None = None
) -> Scenario:
    radio = sc.radio.model_copy(
        update={
            "model": model,
            "fading": False,
            "wall_loss_db": {**sc.radio.wall_loss_db, **losses},
            "turn_loss_db": sc.radio.turn_loss_db if turn_db is None else turn_db,
        }
    )
    return sc.model_copy(update={"radio": radio, "relays": relays})


def walk(
    sc: Scenario, model: str, losses: dict[str, float], turn_db: float | None = None
) -> list[tuple[int, float, float]]:
    """(t, e2e Mbps, power dBm) each second of the walk, no relays."""
    w = World(_variant(sc, model, losses, 0, turn_db), seed=1)
    out = []
    for t in range(int(w.leader_script.end_s) + 1):
        w.advance(float(t))
        lb = w.links()
        out.append((t, lb.e2e_mbps, lb.hops[0].power_dbm))
    return out


def cost_per_sim_s(sc: Scenario, model: str, seconds: int = 20) -> float:
    """CPU seconds the radio spends per simulated second with the relays walking behind
    the leader along its route (positions moved every tick, so no memo hit is free)."""
    w = World(_variant(sc, model, {}, min(2, len(sc.relay))), seed=1)
    if model == "dominant-path":
        w.radio.corner_graph()  # built once per world: timed on its own
    ticks = int(seconds * sc.tick_hz)
    span = w.leader_script.end_s - sc.leader.start_s
    t0 = time.process_time()
    for k in range(ticks):
        # Ticks spread over the whole walk, the relays 8 m and 16 m of walk behind on the route.
        t = sc.leader.start_s + span * k / ticks
        w.advance(t)
        for i, r in enumerate(w.relays):
            p = w.leader_script.pose(max(0.0, t - 40.0 * (i + 1)))
            r.x_m, r.y_m = p.x_m, p.y_m
        w.links()
        for i in range(len(w.relays)):
            w.yagi_rssi_dbm(i)
    return (time.process_time() - t0) / seconds


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="corridor")
    ap.add_argument("--set", action="append", default=[], metavar="MATERIAL=DB")
    ap.add_argument("--turn", type=float, default=None, help="radio.turn_loss_db (dB per 90 deg)")
    ap.add_argument("--no-cost", action="store_true", help="skip the cost table")
    args = ap.parse_args()
    losses = {k: float(v) for k, v in (s.split("=", 1) for s in args.set)}
    sc = load_scenario(args.scenario)
    runs = {m: walk(sc, m, losses, args.turn) for m in MODELS}
    print(
        f"{args.scenario}, no relays, seed 1, no fading; wall overrides {losses or 'none'}, "
        f"turn loss {sc.radio.turn_loss_db if args.turn is None else args.turn} dB per 90 deg"
    )
    print("| t (s) | " + " | ".join(f"{m} e2e Mbps (dBm)" for m in MODELS) + " |")
    print("|---|" + "---|" * len(MODELS))
    for t in TIMES_S:
        cells = []
        for m in MODELS:
            row = next((r for r in runs[m] if r[0] == t), None)
            cells.append("-" if row is None else f"{row[1]:.1f} ({row[2]:.1f})")
        print(f"| {t} | " + " | ".join(cells) + " |")
    for m in MODELS:
        broke = next((t for t, e, _ in runs[m] if e == 0.0), None)
        print(f"{m}: link broken at {broke} s")
    if args.no_cost:
        return 0
    print()
    print("| world | model | radio CPU ms per simulated s | corner graph (CPU) |")
    print("|---|---|---|---|")
    for name in (
        args.scenario,
        "generated:office:0",
        "generated:office:1",
        "generated:corridors:3",
        "generated:corridors:5",
    ):
        world = load_scenario(name)
        for m in MODELS:
            graph = "-"
            if m == "dominant-path":
                t0 = time.process_time()
                g = World(_variant(world, m, {}, 0), seed=1).radio.corner_graph()
                ms = 1000 * (time.process_time() - t0)
                graph = f"{len(g.nodes)} bend points, built in {ms:.0f} ms"
            c = cost_per_sim_s(world, m)
            print(f"| {name} | {m} | {1000 * c:.1f} | {graph} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
