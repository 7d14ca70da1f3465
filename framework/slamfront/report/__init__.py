"""The human side of a run: ``metrics.json``, ``report.md`` and PNG plots."""
