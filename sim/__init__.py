"""h4bench: sim."""
