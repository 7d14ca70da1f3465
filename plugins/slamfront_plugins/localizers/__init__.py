"""Built-in localizers (none yet)."""
