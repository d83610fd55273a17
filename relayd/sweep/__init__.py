"""Monte Carlo sweeps of the simulator (`relayd sweep`): a grid of scenarios, relay counts,
seeds and parameter values, run on a Dask cluster, collected into runs.csv and report.md.

- `grid`: the grid itself (parsing `--set`, expanding it into `RunSpec`s, run folders).
- `child`: runs ONE simulation in its own process (`python -m relayd.sweep.child`).
- `task`: what a Dask worker executes: the child with a wall-time limit, its results read back.
- `driver`: submits the grid, retries once, resumes, shows progress, writes the results.
- `report`: report.md with mean/band plots per grid cell.
"""
