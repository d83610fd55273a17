"""relayd benchmarks: figures against SPEC section 6, printed as a markdown table (see bench/run.py)."""
