"""Built-in backends (none yet)."""
