"""h4bench: trajectories."""
