"""relayd benchmarks: figures against the project's performance targets, printed as a markdown table (see bench/run.py)."""
