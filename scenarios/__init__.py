"""h4bench: scenarios."""
