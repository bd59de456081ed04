"""The ``h4bench`` command line."""

from __future__ import annotations

import contextlib
import importlib.metadata
import io
import math
import os
import sys
from pathlib import Path
from typing import Optional

import typer

from h4bench.scenarios.cli_output import Progress, print_summary, table1
from h4bench.scenarios.cli_certified import certified_lines, exit_if_certificate_failed, exit_if_contradicted
from h4bench.scenarios.exit_codes import EXIT_INCONSISTENT, EXIT_METHOD_FAILED

app = typer.Typer(
    name="h4bench",
    help="Guaranteed identification of the H4 parallel robot's dynamic parameters: simulate, identify, check.",
    no_args_is_help=True,
    add_completion=False,
)


@contextlib.contextmanager
def native_output_to_stderr():
    """While a command runs, whatever native code (a solver's banner, a C library) writes to file descriptor 1
    goes to standard error; the command's own output (``typer.echo``, rich) still reaches standard output. So
    ``--json`` prints exactly one JSON document on stdout."""
    try:
        stdout_fd = sys.stdout.fileno()
    except (AttributeError, OSError, io.UnsupportedOperation):
        stdout_fd = None  # e.g. a test runner's captured stdout: only the native fd 1 needs moving
    sys.stdout.flush()
    saved = os.dup(1)
    previous = sys.stdout
    try:
        os.dup2(2, 1)
        if stdout_fd == 1:
            sys.stdout = io.TextIOWrapper(io.FileIO(saved, "w", closefd=False), encoding=previous.encoding or "utf-8",
                                          line_buffering=True)
        yield
    finally:
        try:
            sys.stdout.flush()
        finally:
            sys.stdout = previous
            os.dup2(saved, 1)
            os.close(saved)


@app.callback()
def main(ctx: typer.Context) -> None:
    """h4bench: simulate the H4, identify its 14 dynamic parameters with guaranteed boxes, check them."""
    ctx.with_resource(native_output_to_stderr())


@contextlib.contextmanager
def native_stderr_captured(sink: list):
    """What native code (urdfdom's ``Error:`` lines) writes to file descriptor 2 goes to a temporary file; its
    text is appended to ``sink`` on exit, so a failure can quote it in its one error line."""
    import tempfile

    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        try:
            os.dup2(tmp.fileno(), 2)
            yield sink
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            sink.append(tmp.read().decode("utf-8", "replace"))


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(2)


@app.command()
def run(
    name: str = typer.Argument(..., help="scenario name (h4bench scenarios) or a TOML path"),
    seed: Optional[int] = typer.Option(None, help="seed (default: the scenario's)"),
    model: Optional[Path] = typer.Option(None, help="another MJCF model of the H4"),
    out: Optional[Path] = typer.Option(None, help="output folder (default runs/NAME)"),
    quick: bool = typer.Option(False, "--quick", help="the reduced size used in CI"),
    as_json: bool = typer.Option(False, "--json", help="print result.json instead of the table"),
    scheduler: Optional[str] = typer.Option(None, help="Dask scheduler address for campaigns (host:port)"),
    workers: Optional[int] = typer.Option(None, help="local worker processes for campaigns"),
    only: Optional[int] = typer.Option(None, help="campaigns: re-run this run index alone, with its replay"),
    fresh: bool = typer.Option(False, "--fresh", help="campaigns: recompute every run instead of resuming"),
    methods: Optional[str] = typer.Option(None, help="estimators a,b,c (names, package.module:attribute, or all: "
                                          "every registered one but certified, which --error-model derived adds; h4bench estimators lists "
                                          "them), replacing the "
                                          "spec's [estimators] methods"),
    runs: Optional[int] = typer.Option(None, help="campaigns: the number of runs (replaces campaign.runs)"),
    method_timeout: Optional[float] = typer.Option(None, help="seconds each estimator may run per run (default: no "
                                                   "limit); a method over it is failed: timeout"),
    error_model: str = typer.Option("tuned", help="tuned (the spec's bound) or derived (enclosure: add the "
                                    "certified box from the [error_model] table and check its certificate; tx40: "
                                    "add the certified box under [tx40.error_model])"),
) -> None:
    """Run a scenario headless; write runs/NAME/ (result.json, report.md, PNG plots, dataset, replay.rrd).

    Exit codes: 0 done (every method gave a box or proved the data inconsistent, in every run); 1 a certified
    box's certificate failed (a stated assumption below the simulated truth, a row violation; in some run of a
    campaign): named on stderr and in the first lines of report.md; 3 (tx40 --error-model derived) the log
    contradicts a stated motion bound of the certified box (no box); 2 bad option,
    scenario or method (nothing computed) or a failed run; 4 some method failed (in some run; the results are
    still written, the failures in the methods' entries); 130 interrupted.
    """
    from h4bench.scenarios.campaign import CampaignInterrupted
    from h4bench.scenarios.runner import run_scenario

    _importable_from_cwd(methods)
    try:
        _check_timeout(method_timeout)
        with Progress(enabled=not as_json and sys.stderr.isatty()) as progress:
            result = run_scenario(name, seed=seed, model=model, out=out, quick=quick, progress=progress,
                                  scheduler=scheduler, workers=workers, only=only, fresh=fresh,
                                  methods=methods, runs=runs, method_timeout=method_timeout,
                                  error_model=error_model)
    except CampaignInterrupted as exc:
        typer.secho(f"stopped: {exc}", fg=typer.colors.YELLOW, err=True)
        raise typer.Exit(130)
    except ValueError as exc:  # ScenarioError, ModelError, DatasetError, InconsistentDataError, ...
        _fail(str(exc))
    except KeyboardInterrupt:
        typer.secho("stopped: interrupted; nothing of this run was kept (run folders are written whole or not at all)",
                    fg=typer.colors.YELLOW, err=True)
        raise typer.Exit(130)
    if as_json:
        typer.echo(_json_text(result))
    else:
        print_summary(result)
        if result.get("kind") in ("paper", "certified"):
            from rich.console import Console

            table = table1(result)
            if table is not None:
                Console().print(table)
        typer.echo(f"written: {out or Path('runs') / result['scenario']}/")
    exit_if_contradicted(result)
    exit_if_certificate_failed(result)
    _exit_if_failed(result, EXIT_METHOD_FAILED)


def _importable_from_cwd(methods: str | None) -> None:
    """A ``module:attribute`` method is imported as ``python -m`` would: the working directory first on sys.path
    (so ``examples.shrunk_hull:estimate`` works from the repository's root; process-pool workers inherit it)."""
    if methods and ":" in methods and os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())


def _json_text(result: dict) -> str:
    """The result as strict JSON (non-finite numbers null, as in result.json)."""
    from h4bench.scenarios.rundir import finite_json

    return finite_json(result)


@app.command()
def estimators(as_json: bool = typer.Option(False, "--json", help="print the list as JSON")) -> None:
    """List every estimator (built-in, entry point of group h4bench.estimators) and the plugins that fail to load."""
    from h4bench.scenarios.judging import describe_estimators

    found = describe_estimators()
    if as_json:
        typer.echo(_json_text(found))
        return
    for e in found["estimators"]:
        level = "" if e["level"] is None else f" level {e['level']:g}"
        typer.echo(f"{e['name']:14s} {e['kind']:11s} rigorous={str(e['rigorous']):5s}{level:11s} "
                   f"[{e['origin']}] {e['description']}")
    for b in found["broken"]:
        typer.secho(f"{b['name']:14s} BROKEN: {b['error']}", fg=typer.colors.RED)


@app.command("check-estimator")
def check_estimator(
    name: str = typer.Argument(..., help="an estimator: a name (h4bench estimators), package.module:attribute "
                                         "(importable from the working directory) or an entry point"),
    seed: int = typer.Option(0, help="seed of the generated problems"),
    as_json: bool = typer.Option(False, "--json", help="print the report as JSON instead of the table"),
    method_timeout: Optional[float] = typer.Option(None, help="seconds the estimator may run per problem (default: "
                                                   "no limit); over it, that problem's box check fails: timeout"),
) -> None:
    """Check an estimator on generated problems against the exact hull and proven-feasible points
    (h4bench.ident.estimators.check_estimator; docs/estimators.md). Exits 1 naming each failed check (with its
    proof point when the box is not outer), 0 when every check passes."""
    from h4bench.ident.estimators import check_estimator as run_checks

    _importable_from_cwd(name)
    try:
        _check_timeout(method_timeout)
    except ValueError as exc:
        _fail(str(exc))
    report = run_checks(name, seed=seed, timeout=method_timeout)
    typer.echo(_json_text(report.to_dict()) if as_json else report.table())
    for r in report.failures:
        proof = f"; proof point {r.proof['point']}" if r.proof else ""
        typer.secho(f"failed: {r.check} on {r.problem}: {r.detail}{proof}", fg=typer.colors.RED, err=True)
    if not report.passed:
        raise typer.Exit(1)


@app.command()
def scenarios() -> None:
    """List the scenarios."""
    from h4bench.scenarios.registry import load_spec
    from h4bench.scenarios.spec import available

    for name in available():
        spec = load_spec(name)
        typer.echo(f"{name:20s} {spec['description']}")


@app.command()
def identify(
    file: Path = typer.Argument(..., help="CSV log: header t,q1..q4,tau1..tau4 (SI units; with --urdf "
                                "t,q1..qn,tau1..taun, joint side)"),
    bound: Optional[str] = typer.Option(None, help="bound on |tau - W theta| for every raw sample [N m]: one "
                                        "number, 4 (n) comma-separated numbers (joints 1..4 (n)) or, H4 only, a "
                                        ".toml/.csv file (required unless --spec)"),
    spec: Optional[Path] = typer.Option(None, help="an error specification (TOML [error_model], optional "
                                        "[certified]) instead of --bound: the certified box of the derived "
                                        "interval equation (the H4, or with --urdf any serial robot)"),
    urdf: Optional[Path] = typer.Option(None, help="a serial robot's URDF: identify its base parameters in a "
                                        "physical prior (--mass, --reach) instead of the H4's 14"),
    mass: Optional[str] = typer.Option(None, help="--urdf: total mass of the prior [kg] (default 2 x the URDF's)"),
    reach: Optional[str] = typer.Option(None, help="--urdf: reach of the prior [m] (default: the sum of the "
                                        "joint-origin offsets + the last link's centre-of-mass distance)"),
    friction: bool = typer.Option(True, "--friction/--no-friction", help="--urdf: viscous and Coulomb friction"),
    rotor: bool = typer.Option(True, "--rotor/--no-rotor", help="--urdf: rotor inertia per joint"),
    offset: bool = typer.Option(True, "--offset/--no-offset", help="--urdf: torque offset per joint"),
    coupled_wrist: Optional[str] = typer.Option(None, help="--urdf: A,B (joints 1..n): the motor of joint B also "
                                                "turns with joint A (e.g. 5,6 on a Staubli wrist)"),
    cutoff_hz: str = typer.Option("100", help="--urdf: Butterworth cut-off on q [Hz]"),
    decimation: str = typer.Option("100", help="--urdf: decimation factor of the parallel filter"),
    torque_timing: str = typer.Option("hold", help="H4: hold (each logged torque is a command held over its "
                                      "step: a controller's log, the simulator's) | sample (a torque measured "
                                      "at the sample instant)"),
    method: str = typer.Option("hull", help="estimator(s): a name (hull | cgsp | wls | h4bench estimators), "
                               "package.module:attribute, a comma-separated list or all; judged against the "
                               "exact hull (narrower-than-hull verdict)"),
    prior: Optional[Path] = typer.Option(None, help="per-parameter prior: .toml ([Imot1] lower = .. upper = ..) "
                                         "or .csv (name,lower,upper); unnamed parameters keep the pair below"),
    prior_lower: str = typer.Option("0.0", help="prior lower bound of every parameter (not in --prior)"),
    prior_upper: str = typer.Option("2.0", help="prior upper bound of every parameter (not in --prior)"),
    model: Optional[Path] = typer.Option(None, help="MJCF model giving the robot's geometry"),
    out: Optional[Path] = typer.Option(None, help="output folder (default runs/identify-<file stem>)"),
    as_json: bool = typer.Option(False, "--json", help="print result.json (the only output on stdout)"),
    pairs: Optional[str] = typer.Option(None, help="the feasible set's projections onto pairs, feasible_set.png: "
                                        "auto (the most coupled) or NAME:NAME,... (e.g. Fv1:Fs1,Imot1:Mnac)"),
    method_timeout: Optional[float] = typer.Option(None, help="seconds each method may run (default: no limit); "
                                                   "a method over it is failed: timeout"),
) -> None:
    """The estimators on a user's own data; prints the table (or result.json) and writes result.json.

    Exit codes:
    0 done: every requested method gave a box or proved the data inconsistent;
    2 bad option, file or data, or a method that cannot be resolved (one error line on stderr, nothing computed);
    3 the data are proven inconsistent with the bound (result.json still written, with the smallest consistent
    bound in --bound's units and the processed rows' one), or with --spec a stated qd_max / qdd_max is below what
    the positions prove (each named on stderr: entry, joint, stated value, proven lower bound; result.json still
    written, status spec_contradicted, no box);
    4 some requested method failed (raised, exited, timed out, changed its inputs, returned no box; result.json
    still written, the failure in its entry).
    """
    from h4bench.scenarios.identify import METHODS, OptionError
    from h4bench.scenarios.judging import parse_methods

    _importable_from_cwd(method)
    try:
        _check_timeout(method_timeout)
        try:
            parse_methods(method)
        except ValueError as exc:
            raise OptionError(f"--method must name estimators ({' | '.join(METHODS)}, several comma-separated, all, "
                              f"or an estimator plugin), got {method!r}: {exc}") from None
        if spec is not None and urdf is None:
            result = _identify_h4_spec(file, spec, bound, method, prior, prior_lower, prior_upper, model, out,
                                       torque_timing, pairs)
        elif spec is not None:
            result = _identify_spec(file, urdf, spec, bound, method, mass, reach, friction, rotor, offset,
                                    coupled_wrist, cutoff_hz, decimation, prior, model, out, pairs, torque_timing,
                                    as_json)
        elif bound is None:
            raise OptionError("--bound is required (or --spec FILE for the certified box), got neither")
        elif urdf is not None:
            if torque_timing != "hold":
                raise OptionError("--torque-timing applies to the H4 path (the --urdf processing evaluates the "
                                  f"regressor at the sample instants), got --torque-timing {torque_timing}")
            result = _identify_urdf(file, urdf, bound, method, mass, reach, friction, rotor, offset, coupled_wrist,
                                    cutoff_hz, decimation, prior, model, out, pairs, method_timeout)
        else:
            for name, value in (("--mass", mass), ("--reach", reach), ("--cutoff-hz", cutoff_hz != "100" or None),
                                ("--decimation", decimation != "100" or None), ("--no-friction", not friction or None),
                                ("--no-rotor", not rotor or None), ("--no-offset", not offset or None),
                                ("--coupled-wrist", coupled_wrist)):
                if value is not None:
                    raise OptionError(f"{name} needs --urdf (the H4's settings are its spec's), got {name}")
            result = _identify_h4(file, bound, method, prior, prior_lower, prior_upper, model, out, torque_timing,
                                  pairs, method_timeout)
    except (ValueError, OSError) as exc:  # OptionError, DatasetError, ProcessingError, ModelError, ...
        _fail(str(exc))
    if as_json:
        typer.echo(_json_text(result))
    elif (result.get("methods", {}).get("certified") or {}).get("status") != "spec_contradicted":
        print_summary(result)
        if result.get("parameter_expressions"):
            import textwrap

            if "min_consistent_bound_raw" in result:
                typer.echo(f"min consistent bound / ||h||_1 (raw rows, approximate): "
                           f"{result['min_consistent_bound_raw']:.4g} N m")
            if "dominant" in result.get("certified", {}):
                c = result["certified"]
                typer.echo(f"certified: {c['rows']} rows, dominant term {c['dominant']}; stated motion bounds "
                           "not contradicted by the data")
            typer.echo("base parameters (base <- standard):")
            for n, e in zip(result["parameters"], result["parameter_expressions"]):
                typer.echo(textwrap.fill(f"{n} = {e}", width=80, subsequent_indent="    "))
    if result.get("kind") == "identify" and not as_json and "certified" not in result:
        typer.echo("narrower-than-hull check: " + _verdict(result))
    if not as_json:
        certified_lines(result)
    exit_if_contradicted(result)
    if result.get("consistent") is False:
        typer.secho(f"error: the data are inconsistent with the bound (proven); {_smallest_bound(result)}",
                    fg=typer.colors.RED, err=True)
        raise typer.Exit(EXIT_INCONSISTENT)
    _exit_if_failed(result, EXIT_METHOD_FAILED)


def _check_timeout(seconds) -> None:
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        from h4bench.scenarios.identify import OptionError

        raise OptionError(f"--method-timeout must be a number of seconds > 0, got {seconds!r}")


def _verdict(result: dict) -> str:
    """The narrower-than-hull line of ``identify``: it speaks only of boxes that exist."""
    unsound = result.get("unsound") or []
    if unsound:
        return f"UNSOUND {', '.join(unsound)}"
    if not result.get("hull_reference"):
        return "not run (no hull box)"
    checked = [n for n, m in result["methods"].items() if m.get("unsound") is False]
    return "no guaranteed box is narrower than the exact hull" if checked else "no guaranteed box to check"


def _smallest_bound(result: dict) -> str:
    """The exit-3 message: the smallest consistent bound in --bound's units (raw rows; per joint when the bound
    is per joint) and the processed rows' one beside it."""
    sc = (result.get("inconsistency") or {}).get("smallest_consistent")
    if sc is None:
        failed = [m for m in result["methods"].values() if m.get("min_bound") is not None]
        smallest = (failed[0]["min_bound"] if failed else (result.get("inconsistency") or {}).get("min_bound")
                    or result["wls"]["consistency"]["min_bound"])
        return f"the smallest consistent bound of the processed rows is {smallest:.6g} N m"
    processed = f"the processed rows' smallest consistent bound is {sc['processed']:.6g} N m (filter gain {sc['gain']:.4g})"
    if isinstance(result.get("bound"), list):
        per = ",".join(f"{v:.6g}" for v in sc["raw"])
        return (f"consistent bounds in --bound's units (raw rows, per joint: the given ones scaled up together) are "
                f"--bound {per} N m; {processed}")
    return f"the smallest consistent bound in --bound's units (raw rows) is {sc['raw_max']:.6g} N m; {processed}"


def _failed_methods(result: dict) -> list[str]:
    """Requested methods without a box or a proof of emptiness (in a campaign: in some run)."""
    return [n for n, m in (result.get("methods") or {}).items()
            if isinstance(m, dict) and (m.get("status") == "failed" or m.get("failure_messages"))]


def _exit_if_failed(result: dict, code: int) -> None:
    failed = _failed_methods(result)
    if failed:
        typer.secho(f"error: method(s) without a box: {', '.join(failed)} (see their entries in result.json)",
                    fg=typer.colors.RED, err=True)
        raise typer.Exit(code)


def _identify_spec(file, urdf, spec, bound, method, mass, reach, friction, rotor, offset, coupled_wrist, cutoff_hz,
                   decimation, prior, model, out, pairs, torque_timing, as_json=False) -> dict:
    """``--urdf ... --spec``: the certified box of a serial robot (:mod:`scenarios.identify_serial_certified`); options
    of the tuned path are refused."""
    from h4bench.scenarios.identify import OptionError, parse_number

    for name, value in (("--bound", bound), ("--method", None if method == "hull" else method),
                        ("--cutoff-hz", None if cutoff_hz == "100" else cutoff_hz),
                        ("--decimation", None if decimation == "100" else decimation), ("--prior", prior),
                        ("--model", model), ("--pairs", pairs),
                        ("--torque-timing", None if torque_timing == "hold" else torque_timing)):
        if value is not None:
            raise OptionError(f"{name} does not apply with --spec (the bound, the processing and the torque timing "
                              f"come from the spec file; the box is the certified one), got {name} {value}")
    n = _urdf_joints(urdf)
    from h4bench.scenarios.identify_serial_certified import identify_urdf_spec

    kw = dict(mass=None if mass is None else parse_number(mass, "--mass", positive=True),
              reach=None if reach is None else parse_number(reach, "--reach", positive=True),
              friction=friction, rotor_inertia=rotor, offset=offset, coupled_wrist=_coupled_wrist(coupled_wrist, n),
              out=out)
    with Progress(enabled=not as_json and sys.stderr.isatty()) as progress:  # minutes on a 6-7 joint arm
        return identify_urdf_spec(file, urdf, spec, progress=progress, **kw)


def _identify_urdf(file, urdf, bound, method, mass, reach, friction, rotor, offset, coupled_wrist, cutoff_hz,
                   decimation, prior, model, out, pairs=None, timeout=None) -> dict:
    from h4bench.scenarios.identify import OptionError, identify_urdf_csv, parse_joint_bound, parse_number

    for name, value in (("--prior", prior), ("--model", model)):
        if value is not None:
            raise OptionError(f"{name} is for the H4; with --urdf the prior is physical (--mass, --reach), got "
                              f"{name} {value}")
    n = _urdf_joints(urdf)
    wrist = _coupled_wrist(coupled_wrist, n)
    dec = parse_number(decimation, "--decimation", positive=True)
    if dec != int(dec):
        raise OptionError(f"--decimation must be an integer >= 1, got {decimation!r}")
    return identify_urdf_csv(
        file, urdf, parse_joint_bound(bound, n), method,
        mass=None if mass is None else parse_number(mass, "--mass", positive=True),
        reach=None if reach is None else parse_number(reach, "--reach", positive=True),
        friction=friction, rotor_inertia=rotor, offset=offset, coupled_wrist=wrist,
        cutoff_hz=parse_number(cutoff_hz, "--cutoff-hz", positive=True), decimation=int(dec), out=out, pairs=pairs,
        timeout=timeout)


def _urdf_joints(urdf) -> int:
    """The number of joints of ``--urdf`` (the parser's own messages on stderr); OptionError names the option."""
    from h4bench.ident.robots.serial import SerialRobot
    from h4bench.scenarios.identify import OptionError

    if not Path(urdf).is_file():
        raise OptionError(f"--urdf must name an existing URDF file, got {str(urdf)!r} (not found)")
    native: list = []
    try:
        with native_stderr_captured(native):
            n = SerialRobot(urdf, friction=False, rotor_inertia=False, offset=False).n_joints
    except (ValueError, RuntimeError) as exc:
        said = " ".join(" ".join(native).split())
        raise OptionError(f"--urdf {str(urdf)!r} is not a usable serial robot: {exc}"
                          + (f" (parser: {said})" if said else "")) from None
    if "".join(native).strip():
        sys.stderr.write("".join(native))
    return n


def _coupled_wrist(coupled_wrist, n: int):
    """``--coupled-wrist A,B`` (1-based) -> 0-based (a, b) or None; OptionError names the option."""
    from h4bench.scenarios.identify import OptionError

    if coupled_wrist is None:
        return None
    try:
        wrist = tuple(int(x) - 1 for x in str(coupled_wrist).split(","))
    except ValueError:
        wrist = ()
    if len(wrist) != 2 or wrist[0] == wrist[1] or not all(0 <= j < n for j in wrist):
        raise OptionError(f"--coupled-wrist must be two distinct joints A,B in 1..{n}, got {coupled_wrist!r}")
    return wrist


def _identify_h4_spec(file, spec, bound, method, prior, prior_lower, prior_upper, model, out, torque_timing,
                      pairs) -> dict:
    from h4bench.scenarios.identify import OptionError, load_prior, parse_number
    from h4bench.scenarios.identify_certified import identify_certified_csv

    for name, value in (("--bound", bound), ("--method", None if method == "hull" else method),
                        ("--torque-timing", None if torque_timing == "hold" else torque_timing), ("--pairs", pairs)):
        if value is not None:
            raise OptionError(f"{name} does not apply with --spec (the certified box rests on the specification "
                              f"alone, its torque_timing included), got {name} {value}")
    lo, hi = parse_number(prior_lower, "--prior-lower"), parse_number(prior_upper, "--prior-upper")
    box = load_prior(prior, lo, hi) if prior is not None else (lo, hi)
    return identify_certified_csv(file, spec, box, model=model, out=out)


def _identify_h4(file, bound, method, prior, prior_lower, prior_upper, model, out, torque_timing="hold",
                 pairs=None, timeout=None) -> dict:
    from h4bench.scenarios.identify import OptionError, identify_csv, load_prior, parse_bound, parse_number

    bounds = parse_bound(bound)
    lo, hi = parse_number(prior_lower, "--prior-lower"), parse_number(prior_upper, "--prior-upper")
    if not lo < hi:
        raise OptionError(f"--prior-lower must be < --prior-upper, got {lo:g} and {hi:g}")
    box = load_prior(prior, lo, hi) if prior is not None else (lo, hi)
    if torque_timing not in ("hold", "sample"):
        raise OptionError(f"--torque-timing must be hold or sample, got {torque_timing!r}")
    return identify_csv(file, bounds, method=method, prior=box, model=model, out=out, torque_timing=torque_timing,
                        pairs=pairs, timeout=timeout)


@app.command()
def export(
    run_dir: Path = typer.Argument(..., help="a run folder written by h4bench run (e.g. runs/paper)"),
    log_csv: Path = typer.Argument(..., help="the CSV to write (t,q1..q4,tau1..tau4; .gz: gzip-compressed)"),
    spec: Optional[Path] = typer.Option(None, help="where the run's error specification goes (default spec.toml "
                                        "beside the CSV)"),
) -> None:
    """Write a run's dataset as the CSV identify reads, with its true error specification (for identify --spec).

    Then: h4bench identify LOG_CSV --spec SPEC. Refuses to replace a file h4bench did not write. Exit code 2: bad
    run folder or target (one error line).
    """
    from h4bench.scenarios.export import export_run

    try:
        written = export_run(run_dir, log_csv, spec)
    except (ValueError, OSError) as exc:
        _fail(str(exc))
    typer.echo(f"written: {written['csv']} ({written['rows']} rows, {written['seconds']:.3f} s), {written['spec']}")
    typer.echo(f"next: h4bench identify {written['csv']} --spec {written['spec']}  (the truth: {run_dir}/result.json "
               "\"true\")")


@app.command()
def replay(
    file: Path = typer.Argument(..., help="a replay.rrd written by h4bench run"),
    web: bool = typer.Option(False, "--web", help="serve the web viewer instead of the native one"),
    bind: str = typer.Option("127.0.0.1", help="IP address the viewer's servers listen on (0.0.0.0: every "
                             "interface, reachable from other machines)"),
) -> None:
    """Open a run's replay in the Rerun viewer (it stops with this command: Ctrl-C, SIGTERM)."""
    from h4bench.scenarios.replay import open_viewer

    try:
        open_viewer(file, web=web, bind=bind)
    except (ValueError, FileNotFoundError) as exc:
        _fail(str(exc))


@app.command()
def controller(
    bandwidth_hz: float = typer.Option(15.0, help="requested tracking bandwidth [Hz]"),
    model: Optional[Path] = typer.Option(None, help="MJCF model"),
) -> None:
    """Print the joint controller design: gains, bandwidth, margins, step response (python-control)."""
    import numpy as np

    from h4bench import ident
    from h4bench import sim

    try:
        geometry = sim.H4Geometry.from_model(sim.load_model(model))
        design, _ = sim.default_controller(geometry, np.asarray(ident.NOMINAL_PARAMETERS), bandwidth_hz=bandwidth_hz)
    except ValueError as exc:
        _fail(str(exc))
    typer.echo(design.report())


@app.command()
def compare(a: Path = typer.Argument(..., help="a result.json (or its run folder)"),
            b: Path = typer.Argument(..., help="another result.json (or its run folder)")) -> None:
    """Where two runs first differ: the stage (trajectory, controller, feed-forward, dataset), then the results."""
    from h4bench.scenarios.compare import compare_results, load_result

    try:
        lines, count = compare_results(load_result(a), load_result(b))
    except ValueError as exc:
        _fail(str(exc))
    typer.echo("\n".join(lines))
    raise typer.Exit(1 if count else 0)


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
