"""The ``h4bench`` command line."""

from __future__ import annotations

import importlib.metadata

import typer

app = typer.Typer(
    name="h4bench",
    help="Guaranteed identification of the H4 parallel robot's dynamic parameters: simulate, identify, check.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback()
def main() -> None:
    """h4bench: simulate the H4, identify its 14 dynamic parameters with guaranteed boxes, check them."""


@app.command()
def version() -> None:
    """Print the versions of h4bench and of the packages its results depend on."""
    for dist in ("h4bench", "mujoco", "numpy", "scipy", "highspy", "toppra", "control", "rerun-sdk"):
        try:
            typer.echo(f"{dist} {importlib.metadata.version(dist)}")
        except importlib.metadata.PackageNotFoundError:
            typer.echo(f"{dist} (not installed)")


if __name__ == "__main__":  # pragma: no cover
    app()
