"""Built-in registrations (none yet)."""
