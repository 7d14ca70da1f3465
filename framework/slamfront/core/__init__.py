"""Pure functions over NumPy arrays: metrics, ground truth, geometry.

Nothing here reads files, writes logs, plots or parses arguments; every function takes
and returns arrays with documented shapes, never mutates its inputs, and is tested on
synthetic data.
"""
