"""Built-in place maps (none yet)."""
