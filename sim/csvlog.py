"""Reading a robot log (CSV) into typed arrays, in bounded memory.

A log is a text file with a header row naming at least the columns ``t, q1..q4, tau1..tau4`` (SI units: s,
rad, N m) (``n_joints=n``: ``t, q1..qn, tau1..taun``, a serial robot's log); other columns are ignored
and never parsed. :func:`read_log` counts the lines once (binary scan),
allocates the (n,) time and the (n, 4) position and torque arrays, and fills them from a streaming parser, so
the peak memory is the 72 bytes per row of the result plus one parser block (about 1 MB of text), instead
of about 12 times the file size for a generic text reader.

Two parsers are available (``engine``): ``"arrow"`` (default), pyarrow's multithreaded CSV reader with the
nine columns typed float64, and ``"numpy"``, numpy's C parser (``numpy.loadtxt``) fed blocks of lines. On the
benchmark's 1M-row log (``benchmarks/bench_csvlog.py``) arrow is several times faster; both give the same
arrays (both round decimal text correctly to the nearest binary64).

A gzip-compressed log (``.csv.gz``, recognised by its magic bytes, whatever its name) is read the same way,
decompressed on the fly (both engines stream it).

Errors are :class:`DatasetError` (a ValueError, also ``sim.DatasetError``) naming the file, and where it applies the column
and the data row (1-based, the header excluded; blank lines are skipped and not counted). A parser failure
(rows of unequal length, a non-numeric value) is located by a second, plain-Python pass over the file, so the
fast path carries no per-row bookkeeping.
"""

from __future__ import annotations

import csv
import gzip
import io
import itertools
from pathlib import Path

import numpy as np

N_JOINTS = 4
COLUMNS = ("t",) + tuple(f"q{i}" for i in range(1, N_JOINTS + 1)) + tuple(f"tau{i}" for i in range(1, N_JOINTS + 1))
ENGINES = ("arrow", "numpy")
_BLOCK_BYTES = 16 << 20  # line-count read size
_ARROW_BLOCK_BYTES = 1 << 20  # pyarrow's parser block (~6000 rows): faster than larger blocks on a 1M-row log
_NUMPY_BLOCK_ROWS = 200_000


class DatasetError(ValueError):
    """A dataset or log file is malformed (missing columns, NaN, non-monotonic time, wrong shapes)."""


def _error(message: str):
    return DatasetError(message)


def columns(n_joints: int = N_JOINTS) -> tuple[str, ...]:
    """The needed columns ``t, q1..qn, tau1..taun`` of an n-joint log."""
    return ("t",) + tuple(f"q{i}" for i in range(1, n_joints + 1)) + tuple(f"tau{i}" for i in range(1, n_joints + 1))


def _is_gzip(path: Path) -> bool:
    with path.open("rb") as fh:
        return fh.read(2) == b"\x1f\x8b"


def _open_binary(path: Path):
    """The file's bytes, decompressed when it is gzip."""
    return gzip.open(path, "rb") if _is_gzip(path) else path.open("rb")


def _open_text(path: Path):
    """The file's text (UTF-8), decompressed when it is gzip; undecodable bytes raise DatasetError later."""
    return io.TextIOWrapper(_open_binary(path), encoding="utf-8", newline="")


def _header(path: Path, delimiter: str, names: tuple[str, ...] = COLUMNS) -> list[str]:
    try:
        with _open_text(path) as fh:
            first = fh.readline()
    except (UnicodeDecodeError, gzip.BadGzipFile, EOFError, OSError) as exc:
        raise _error(f"CSV {str(path)!r} must be UTF-8 text (or gzip-compressed UTF-8 text), got unreadable "
                     f"content: {exc}") from None
    if not first.strip():
        raise _error(f"CSV {str(path)!r} must start with a header row naming the columns {list(names)}, "
                     f"got an empty first line")
    header = [h.strip() for h in next(csv.reader([first], delimiter=delimiter))]
    missing = [c for c in names if c not in header]
    if missing:
        raise _error(f"CSV {str(path)!r} must have columns {list(names)}, missing {missing} (header: {header})")
    dup = sorted({c for c in names if header.count(c) > 1})
    if dup:
        raise _error(f"CSV {str(path)!r} must name each of the columns {list(names)} once, got {dup} repeated "
                     f"(header: {header})")
    return header


def _count_lines(path: Path) -> int:
    """Upper bound on the data rows: newlines in the file (+1 for a last line without one)."""
    count = 0
    last = b"\n"
    with _open_binary(path) as fh:
        while chunk := fh.read(_BLOCK_BYTES):
            count += chunk.count(b"\n")
            last = chunk[-1:]
    return count + (last != b"\n")


def _locate_bad_row(path: Path, delimiter: str, header: list[str], names: tuple[str, ...] = COLUMNS) -> str | None:
    """Plain-Python pass: the first data row with a wrong value count or a non-numeric needed value."""
    idx = {c: header.index(c) for c in names}
    with _open_text(path) as fh:
        reader = csv.reader(fh, delimiter=delimiter)
        next(reader, None)
        k = 0
        for fields in reader:
            if not fields or all(not f.strip() for f in fields):
                continue
            k += 1
            if len(fields) != len(header):
                return (f"data row {k} (line {reader.line_num}) has {len(fields)} values, expected {len(header)} "
                        f"(one per header column)")
            for c, j in idx.items():
                try:
                    float(fields[j])
                except ValueError:
                    return f"column {c} has the non-numeric value {fields[j].strip()!r} at data row {k} (line {reader.line_num})"
    return None


def _check_block(path: Path, name: str, values: np.ndarray, first_row: int) -> None:
    """values: one column of a block, NaN where the cell was empty or null; first_row: its 0-based data row."""
    bad = ~np.isfinite(values)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        group = name.rstrip("0123456789")
        what = "NaN/empty value" if np.isnan(values[k]) else f"the non-finite value {values[k]}"
        raise _error(f"CSV {str(path)!r}: column {group} has {what} at data row {first_row + k + 1} ({name})")


def _arrow_blocks(path: Path, delimiter: str, header: list[str], names: tuple[str, ...] = COLUMNS):
    import pyarrow as pa
    import pyarrow.csv as pacsv

    source = _open_binary(path)
    reader = pacsv.open_csv(
        source,
        read_options=pacsv.ReadOptions(column_names=header, skip_rows=1, block_size=_ARROW_BLOCK_BYTES),
        parse_options=pacsv.ParseOptions(delimiter=delimiter),
        convert_options=pacsv.ConvertOptions(column_types={c: pa.float64() for c in names},
                                             include_columns=list(names), strings_can_be_null=False),
    )
    with source:
        for batch in reader:
            # nulls (empty cells, "nan", "NA", ...) become NaN and are reported by _check_block
            yield [batch.column(c).to_numpy(zero_copy_only=False) for c in names]


def _numpy_blocks(path: Path, delimiter: str, header: list[str], names: tuple[str, ...] = COLUMNS):
    cols = [header.index(c) for c in names]
    with _open_text(path) as fh:
        fh.readline()
        while True:
            lines = list(itertools.islice(fh, _NUMPY_BLOCK_ROWS))
            if not lines:
                return
            lines = [ln for ln in lines if ln.strip()]
            if not lines:
                continue
            block = np.loadtxt(lines, delimiter=delimiter, usecols=cols, dtype=float, ndmin=2)
            if block.shape[1] != len(cols):
                raise ValueError("wrong column count")
            yield [block[:, j] for j in range(len(cols))]


def read_log(path, delimiter: str = ",", engine: str = "arrow", n_joints: int = N_JOINTS
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read a CSV log: returns t (n,) [s], q (n, nj) [rad], tau (n, nj) [N m], float64, C-contiguous.

    n_joints : nj, the columns needed are ``t, q1..q<nj>, tau1..tau<nj>`` (default 4, the H4).

    path : the CSV file; delimiter : one character; engine : ``"arrow"`` or ``"numpy"`` (see the module
    docstring). Raises DatasetError naming the file, the column and the data row for: a missing file, missing
    or repeated columns, rows with the wrong number of values, non-numeric, empty, NaN or infinite values.
    Sampling checks (monotonic, uniform time) are :class:`sim.Dataset`'s.
    """
    path = Path(path)
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    if not isinstance(delimiter, str) or len(delimiter) != 1:
        raise ValueError(f"delimiter must be a single character, got {delimiter!r}")
    if not path.is_file():
        raise _error(f"path must be an existing CSV file, got {str(path)!r} (not found)")
    if isinstance(n_joints, bool) or not isinstance(n_joints, (int, np.integer)) or n_joints < 1:
        raise ValueError(f"n_joints must be an integer >= 1, got {n_joints!r}")
    nj = int(n_joints)
    names = columns(nj)
    header = _header(path, delimiter, names)
    try:
        capacity = _count_lines(path)
    except (OSError, EOFError) as exc:  # a truncated or corrupt gzip stream
        raise _error(f"CSV {str(path)!r} cannot be read to its end: {exc}") from None
    t = np.empty(capacity)
    q = np.empty((capacity, nj))
    tau = np.empty((capacity, nj))
    blocks = (_arrow_blocks(path, delimiter, header, names) if engine == "arrow"
              else _numpy_blocks(path, delimiter, header, names))
    n = 0
    try:
        for cols in blocks:
            m = cols[0].size
            if n + m > capacity:  # cannot happen (every data row ends a line); guard against a miscount
                raise _error(f"CSV {str(path)!r}: more rows than lines ({n + m} > {capacity})")
            for name, values in zip(names, cols):
                _check_block(path, name, values, n)
            t[n:n + m] = cols[0]
            q[n:n + m] = np.column_stack(cols[1:1 + nj])
            tau[n:n + m] = np.column_stack(cols[1 + nj:])
            n += m
    except (ValueError, OSError, EOFError) as exc:  # a truncated gzip: EOFError / BadGzipFile (an OSError)
        if isinstance(exc, DatasetError):
            raise
        try:
            where = _locate_bad_row(path, delimiter, header, names)
        except (ValueError, OSError, EOFError) as again:
            where = f"unreadable content ({again})"
        raise _error(f"CSV {str(path)!r}: {where or exc}") from exc
    if n == 0:
        raise _error(f"CSV {str(path)!r} must have data rows after the header, got none")
    return t[:n], q[:n], tau[:n]
