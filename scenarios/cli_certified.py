"""What ``h4bench`` prints and how it exits for a certified box: the row radius by its parts, the parameters left
at the prior, a stated motion bound the data contradict (exit 3) and a failed certificate (exit 1)."""

from __future__ import annotations

import typer

from h4bench.scenarios.exit_codes import EXIT_INCONSISTENT

__all__ = ["certified_lines", "exit_if_certificate_failed", "exit_if_contradicted"]


def certified_lines(result: dict) -> None:
    """A certified identification's row radius by its parts and the parameters its box leaves at the prior."""
    c = result.get("certified")
    if not isinstance(c, dict):
        return
    rr = c.get("row_radius")
    if rr:
        typer.echo(f"certified row radius: torque side (torque, model, rounding: any theta) max "
                   f"{rr['torque_side_max']:.4g} N m; whole row (+ D |theta| at {rr['at']}) median "
                   f"{rr['total_median']:.4g} N m, max {rr['total_max']:.4g} N m")
    diag = c.get("prior_diagnosis") or {}
    if diag.get("message"):
        typer.secho(f"warning: {diag['message']}", fg=typer.colors.YELLOW, err=True)


def exit_if_contradicted(result: dict) -> None:
    """Exit 3 when the data contradict a stated motion bound of a certified box's specification (each named)."""
    contradicted = (result.get("methods", {}).get("certified") or {}).get("contradicted")
    if contradicted:
        for line in contradicted:
            typer.secho(f"error: {line}", fg=typer.colors.RED, err=True)
        typer.secho("error: no box is claimed (the certified radii rest on the stated bounds); result.json written",
                    fg=typer.colors.RED, err=True)
        raise typer.Exit(EXIT_INCONSISTENT)


def exit_if_certificate_failed(result: dict) -> None:
    """Exit 1 (a check failed) when a certified box's certificate failed: each failed assumption on stderr."""
    cert = result.get("certificate")
    if isinstance(cert, dict) and cert.get("status") == "failed":
        for line in cert.get("failed", []):
            typer.secho(f"error: certificate: {line}", fg=typer.colors.RED, err=True)
        typer.secho("error: the certified box is not certified (the first lines of report.md name why)",
                    fg=typer.colors.RED, err=True)
        raise typer.Exit(1)
