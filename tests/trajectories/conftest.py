"""Shared trajectories for the trajectory tests (designed once per session: each design takes seconds)."""

from __future__ import annotations

import pytest

from h4bench import trajectories as tj


@pytest.fixture(scope="session")
def excitation(geometry):
    """The default 10 s optimised excitation, seed 0."""
    return tj.fourier_excitation(geometry, duration=10.0, seed=0)


@pytest.fixture(scope="session")
def excitation_start(geometry):
    """Its unoptimised start (same seed)."""
    return tj.fourier_excitation(geometry, duration=10.0, seed=0, optimise=False)


@pytest.fixture(scope="session")
def short_excitation(geometry):
    """A 4 s optimised excitation, seed 1."""
    return tj.fourier_excitation(geometry, duration=4.0, seed=1)
