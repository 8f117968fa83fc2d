"""Calibration file formats (SPEC §3.1–3.3): trial CSV, estimate/forward CSV and the calibration JSON.

Every reader turns a malformed file into one :class:`CalFileError` (a ``ValueError``) whose message names the file,
the line where that makes sense, what is wrong and what to do, so the CLI can print it as its one line.
Readers and writers here run on whichever thread calls them (the CLI's main thread, or a GUI worker); they keep no
state between calls.
"""

from __future__ import annotations

import csv
import errno
import json
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from app.core.errors import CalFileError, OutputPathError
from app.core.outputs import check_output, create_temporary, describe_kind, move_into_place
from devices.toml_files import read_json_file

try:  # Arrow's CSV reader and writer: the fast path for big estimate files (a dependency; numpy stays the fallback)
    import pyarrow as _arrow
    import pyarrow.csv as _arrow_csv
except ImportError:  # pragma: no cover - pyarrow is in pyproject's dependencies
    _arrow = None  # type: ignore[assignment]
    _arrow_csv = None  # type: ignore[assignment]
from models.physics import PhysicsConstants

CAL_FORMAT = "sensnake-calibration"
CAL_VERSION = 1

TIME_COLUMN = "time_s"
FORCE_COLUMN = "force_N"
CONDUCTANCE_COLUMN = "conductance_S"

# The unit a column stem must carry; a header with the right stem and another unit (force_kN, time_ms) is refused
# rather than silently misread by a factor of 1000.
_EXPECTED_UNITS = {"time": "s", "force": "N", "conductance": "S"}


@dataclass(frozen=True)
class Trial:
    """One calibration trial (SPEC §3.1): samples of time (s), applied force (N) and conductance (S)."""

    file: str
    time_s: np.ndarray
    force_n: np.ndarray
    conductance_s: np.ndarray


@dataclass(frozen=True)
class SeriesTable:
    """An estimate/forward CSV (SPEC §3.2): ``time_s`` (N,) and one column per sensor, ``values`` (N, S)."""

    file: str
    time_s: np.ndarray
    columns: tuple[str, ...]
    values: np.ndarray
    # Non-numeric cells read as gaps (``allow_gaps``): column name → (how many, first line, its text).
    bad_cells: dict[str, tuple[int, int, str]] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------------------- CSV


def _read_header(path: Path) -> list[str]:
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            for row in csv.reader(handle):
                if row and any(cell.strip() for cell in row):
                    for other in (";", "\t"):
                        if len(row) == 1 and other in row[0]:
                            name = "semicolons" if other == ";" else "tabs"
                            raise CalFileError(f"{path}:1: the columns are separated by {name}; this reads "
                                               "comma-separated files (SPEC §3.1): save it as CSV with commas")
                    return [cell.strip() for cell in row]
    except UnicodeDecodeError as exc:
        raise CalFileError(f"{path}: not a text CSV file ({exc.reason})") from exc
    raise CalFileError(f"{path}: empty file: expected a header row such as 'time_s,force_N,conductance_S'")


def _check_units(path: Path, header: list[str]) -> None:
    for name in header:
        stem, sep, unit = name.rpartition("_")
        if sep and stem in _EXPECTED_UNITS and unit != _EXPECTED_UNITS[stem]:
            raise CalFileError(
                f"{path}:1: column '{name}' is in {unit}, expected '{stem}_{_EXPECTED_UNITS[stem]}': "
                f"convert the column to {_EXPECTED_UNITS[stem]} and rename it"
            )


def _column_index(path: Path, header: list[str], name: str) -> int:
    if name not in header:
        raise CalFileError(f"{path}:1: missing column '{name}' (header is {','.join(header)})")
    if header.count(name) > 1:
        raise CalFileError(f"{path}:1: column '{name}' appears twice")
    return header.index(name)


def _locate_bad_cell(path: Path, header: list[str], indices: list[int], gaps_from: int | None = None) -> CalFileError:
    """Walk the file row by row to report the first unparsable or non-finite cell with its line number.
    Columns at positions ≥ ``gaps_from`` of ``indices`` may be empty or non-finite (gaps); text is still refused."""
    with path.open(newline="", encoding="utf-8-sig") as handle:
        reader = csv.reader(handle)
        seen_header = False
        for row in reader:
            line = reader.line_num
            if not row or not any(cell.strip() for cell in row):
                continue
            if not seen_header:
                seen_header = True
                continue
            for position, index in enumerate(indices):
                gap_ok = gaps_from is not None and position >= gaps_from
                if index >= len(row):
                    return CalFileError(f"{path}:{line}: row has {len(row)} cells, expected {len(header)}")
                cell = row[index].strip()
                if gap_ok and not cell:
                    continue
                try:
                    value = float(cell)
                except ValueError:
                    return CalFileError(f"{path}:{line}: column '{header[index]}' holds '{cell}', not a number")
                if not math.isfinite(value) and not gap_ok:
                    return CalFileError(
                        f"{path}:{line}: column '{header[index]}' is {cell}: every sample must be a finite number "
                        "(remove or repair the row)"
                    )
    return CalFileError(f"{path}: could not parse the numeric columns")


def _gap_cell(cell: str) -> float:
    """A data cell that may be empty (a dropped sample: NaN)."""
    return float(cell) if cell.strip() else math.nan


def _read_with_bad_cells(path: Path, header: list[str], indices: list[int], gaps_from: int,
                         bad_cells: dict[str, tuple[int, int, str]] | None) -> np.ndarray:
    """The slowest path, for a file with text in a data column (``ERR``, ``--``): each such cell is a gap (NaN),
    counted per column in ``bad_cells``; a column with no number at all, text where the time is, or a short row is
    refused (CalFileError naming file, line and column)."""
    rows: list[list[float]] = []
    counts: dict[int, list] = {}
    with path.open(newline="", encoding="utf-8-sig") as handle:
        reader = csv.reader(handle)
        seen_header = False
        for row in reader:
            if not row or not any(cell.strip() for cell in row):
                continue
            if not seen_header:
                seen_header = True
                continue
            line = reader.line_num
            values = []
            for position, index in enumerate(indices):
                if index >= len(row):
                    raise CalFileError(f"{path}:{line}: row has {len(row)} cells, expected {len(header)}")
                cell = row[index].strip()
                try:
                    values.append(float(cell) if cell else math.nan)
                except ValueError:
                    if position < gaps_from:
                        raise CalFileError(f"{path}:{line}: column '{header[index]}' holds '{cell}', not a number")\
                            from None
                    values.append(math.nan)
                    entry = counts.setdefault(index, [0, line, cell])
                    entry[0] += 1
            rows.append(values)
    data = np.array(rows, dtype=np.float64).reshape(len(rows), len(indices))
    for position, index in enumerate(indices[gaps_from:], start=gaps_from):
        if index in counts and not np.isfinite(data[:, position]).any():
            raise CalFileError(f"{path}: column '{header[index]}' holds no number at all (first cell "
                               f"'{counts[index][2]}' at line {counts[index][1]}): drop the column or fix the export")
    if bad_cells is not None:
        for index, (count, line, text) in counts.items():
            bad_cells[header[index]] = (count, line, text[:20])
    return data


def _read_numbers_fast(path: Path, header: list[str], indices: list[int]) -> np.ndarray | None:
    """The columns ``indices`` through Arrow's multithreaded C++ CSV parser (0.06 s against numpy's 0.40 s on a
    30 MB 36-sensor file, docs/BENCHMARKS.md), or None — pyarrow missing, the header not on the first line, or any cell
    Arrow will not read as a number (text, a short row): the caller's numpy path then reads the file and names the
    cell. Empty cells read as NaN, as the numpy path reads them."""
    if _arrow_csv is None:
        return None
    try:
        with path.open("rb") as handle:
            if not handle.readline().strip():
                return None
        names = [f"c{i}" for i in range(len(header))]
        table = _arrow_csv.read_csv(
            path, read_options=_arrow_csv.ReadOptions(column_names=names, skip_rows=1),
            parse_options=_arrow_csv.ParseOptions(newlines_in_values=False),
            convert_options=_arrow_csv.ConvertOptions(
                include_columns=[names[i] for i in indices],
                column_types={names[i]: _arrow.float64() for i in indices}, strings_can_be_null=False))
    except (_arrow.ArrowException, OSError, ValueError):
        return None
    if table.num_rows == 0:
        return None
    return np.column_stack([np.asarray(table.column(i).to_numpy(zero_copy_only=False), dtype=np.float64)
                            for i in range(len(indices))])


def _read_columns(path: Path, header: list[str], indices: list[int], gaps_from: int | None = None,
                  bad_cells: dict[str, tuple[int, int, str]] | None = None) -> np.ndarray:
    """Return the numeric columns ``indices`` as (N, len(indices)) float64; every cell must be finite, except that
    columns at positions ≥ ``gaps_from`` may hold empty or non-finite cells (read as NaN/±inf: the caller's sample
    validation treats them as gaps)."""
    data = _read_numbers_fast(path, header, indices)
    if data is None:
        data = _read_columns_numpy(path, header, indices, gaps_from, bad_cells)
    checked = data if gaps_from is None else data[:, :gaps_from]
    if not np.all(np.isfinite(checked)):
        raise _locate_bad_cell(path, header, indices, gaps_from)
    return data


def _read_columns_numpy(path: Path, header: list[str], indices: list[int], gaps_from: int | None,
                        bad_cells: dict[str, tuple[int, int, str]] | None) -> np.ndarray:
    """:func:`_read_columns` with numpy's loadtxt, and cell by cell where a cell is not a number."""
    try:
        with path.open(encoding="utf-8-sig") as handle:
            lines = [line for line in handle if line.strip()]
    except UnicodeDecodeError as exc:  # a text header over binary data
        raise CalFileError(f"{path}: not a text CSV file past its header (byte {exc.start}: {exc.reason})") from None
    if len(lines) < 2:
        raise CalFileError(f"{path}: no data rows after the header")
    try:
        data = np.loadtxt(lines[1:], delimiter=",", usecols=indices, ndmin=2, dtype=np.float64, comments=None)
    except ValueError:
        if gaps_from is None:
            raise _locate_bad_cell(path, header, indices) from None
        try:  # the slow path only for files with empty cells
            data = np.loadtxt(lines[1:], delimiter=",", usecols=indices, ndmin=2, dtype=np.float64, comments=None,
                              converters=_gap_cell)
        except ValueError:
            data = _read_with_bad_cells(path, header, indices, gaps_from, bad_cells)
    if data.shape[0] == 0:
        raise CalFileError(f"{path}: no data rows after the header")
    return data


def _check_time(path: Path, time_s: np.ndarray, header_line_offset: int = 2) -> None:
    steps = np.diff(time_s)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        row = int(bad[0]) + 1
        what = "repeats" if steps[bad[0]] == 0 else "goes backwards"
        raise CalFileError(
            f"{path}:{row + header_line_offset}: time_s {what} ({time_s[row - 1]:g} s then {time_s[row]:g} s): "
            "samples must be sorted by strictly increasing time"
        )


MAX_LINE_BYTES = 1 << 20  # a row of 1024 sensors at full precision is ~25 kB; a longer line is not a data row
_SCAN_CHUNK_BYTES = 8 << 20


def _check_text(path: Path) -> None:
    """Refuse, before anything is parsed, a file no CSV reader should hold in memory: one with a NUL byte (binary,
    or a sparse/padded file: ``truncate -s 2G``) or a line longer than :data:`MAX_LINE_BYTES`. Reads the file once
    in fixed chunks: memory stays bounded whatever the file's size or padding."""
    run = 0  # bytes since the last newline
    line = 1
    offset = 0
    try:
        with path.open("rb") as handle:
            while chunk := handle.read(_SCAN_CHUNK_BYTES):
                nul = chunk.find(b"\0")
                if nul >= 0:
                    at_line = line + chunk.count(b"\n", 0, nul)
                    raise CalFileError(f"{path}: not a text CSV file: a NUL byte at byte {offset + nul} (line "
                                       f"{at_line}); binary or padded files are refused")
                newlines = np.flatnonzero(np.frombuffer(chunk, dtype=np.uint8) == 10)
                if newlines.size == 0:
                    run += len(chunk)
                else:
                    longest = max(run + int(newlines[0]), int(np.diff(newlines).max(initial=0)))
                    if longest > MAX_LINE_BYTES:
                        raise CalFileError(f"{path}: a line near line {line} is longer than "
                                           f"{MAX_LINE_BYTES // (1 << 20)} MB: not a CSV data row")
                    run = len(chunk) - 1 - int(newlines[-1])
                    line += int(newlines.size)
                if run > MAX_LINE_BYTES:
                    raise CalFileError(f"{path}: line {line} is longer than {MAX_LINE_BYTES // (1 << 20)} MB: not a "
                                       "CSV data row")
                offset += len(chunk)
    except OSError as exc:
        raise CalFileError(f"{path}: cannot be read ({exc.strerror or exc})") from None


def _open_path(path: str | os.PathLike) -> Path:
    resolved = Path(path)
    try:
        kind = describe_kind(os.stat(resolved).st_mode)
    except FileNotFoundError:
        raise CalFileError(f"{resolved}: no such file") from None
    except OSError as exc:
        why = "a symbolic link loop (it leads back to itself)" if exc.errno == errno.ELOOP else exc.strerror
        raise CalFileError(f"{resolved}: cannot be read: {why}") from None
    if kind is not None:
        raise CalFileError(f"{resolved}: is {kind}, not a file to read")
    _check_text(resolved)
    return resolved


def read_trial_csv(path: str | os.PathLike) -> Trial:
    """Read a calibration trial CSV (SPEC §3.1): ``time_s,force_N,conductance_S``, extra columns ignored.

    Raises :class:`CalFileError` for a missing column, a column in other units (``force_kN``), a non-numeric or
    non-finite cell, or unsorted time, naming the file and line.
    """
    file = _open_path(path)
    header = _read_header(file)
    _check_units(file, header)
    indices = [_column_index(file, header, name) for name in (TIME_COLUMN, FORCE_COLUMN, CONDUCTANCE_COLUMN)]
    data = _read_columns(file, header, indices)
    _check_time(file, data[:, 0])
    if np.any(data[:, 2] < 0):
        row = int(np.flatnonzero(data[:, 2] < 0)[0])
        raise CalFileError(f"{file}:{row + 2}: conductance_S is negative ({data[row, 2]:g} S): conductance is ≥ 0")
    return Trial(file=str(file), time_s=data[:, 0].copy(), force_n=data[:, 1].copy(),
                 conductance_s=data[:, 2].copy())


def read_series_csv(path: str | os.PathLike, single_column: str, allow_gaps: bool = False) -> SeriesTable:
    """Read an estimate/forward input CSV (SPEC §3.2): ``time_s`` then one column per sensor.

    ``allow_gaps`` (estimate): a data cell may be empty, NaN/inf or text (``ERR``) — a dropped or bad sample the
    caller's validation turns into a gap; text cells are counted per column in ``bad_cells`` — instead of refusing
    the file; a column with no number at all is refused; time must always be a finite number.

    ``single_column`` is the generic name (``conductance_S`` for estimate, ``force_N`` for forward) that a file with
    exactly one data column may use instead of a sensor name; the caller maps it to the calibration's only sensor.
    """
    file = _open_path(path)
    header = _read_header(file)
    _check_units(file, header)
    time_index = _column_index(file, header, TIME_COLUMN)
    names = [name for i, name in enumerate(header) if i != time_index]
    if not names:
        raise CalFileError(f"{file}:1: no data column after time_s: expected sensor columns or '{single_column}'")
    if any(not name for name in names):
        raise CalFileError(f"{file}:1: a column has an empty name")
    if len(set(names)) != len(names):
        duplicate = next(name for name in names if names.count(name) > 1)
        raise CalFileError(f"{file}:1: column '{duplicate}' appears twice")
    bad_cells: dict[str, tuple[int, int, str]] = {}
    data = _read_columns(file, header, [time_index] + [header.index(name) for name in names],
                         gaps_from=1 if allow_gaps else None, bad_cells=bad_cells)
    _check_time(file, data[:, 0])
    sensors, scales = _unit_suffixes(file, names, single_column)
    values = np.ascontiguousarray(data[:, 1:])
    if np.any(scales != 1.0):
        values *= scales[None, :]
    renamed = dict(zip(names, sensors, strict=True))
    bad_cells = {renamed[name]: cell for name, cell in bad_cells.items()}
    return SeriesTable(file=str(file), time_s=data[:, 0].copy(), columns=tuple(sensors), values=values,
                       bad_cells=bad_cells)


# A sensor column may carry its unit (the GUI's exports do: S01L_uS); bare names are the SPEC §3.2 default unit.
UNIT_SUFFIXES: dict[str, dict[str, float]] = {CONDUCTANCE_COLUMN: {"uS": 1e-6, "S": 1.0}, FORCE_COLUMN: {"N": 1.0}}


def _unit_suffixes(path: Path, names: list[str], single_column: str) -> tuple[list[str], np.ndarray]:
    """Sensor names without a unit suffix and the factor to the SPEC unit (``S06B_uS`` → ``S06B`` × 1e-6); a sensor
    given twice (``S06B`` and ``S06B_uS``) is refused."""
    units = UNIT_SUFFIXES.get(single_column, {})
    sensors, scales = [], []
    for name in names:
        stem, sep, unit = name.rpartition("_")
        if sep and stem and name != single_column and unit in units:
            sensors.append(stem)
            scales.append(units[unit])
        else:
            sensors.append(name)
            scales.append(1.0)
    if len(set(sensors)) != len(sensors):
        twice = next(name for name in sensors if sensors.count(name) > 1)
        raise CalFileError(f"{path}:1: sensor '{twice}' has two columns (with and without a unit suffix)")
    return sensors, np.array(scales)


def with_unit_suffixes(columns: Sequence[str], values: np.ndarray, quantity: str) -> tuple[list[str], np.ndarray]:
    """``--units suffixed``: each column named with its unit, as the GUI's exports are — forces ``<name>_N``,
    conductance ``<name>_uS`` (values × 1e6). A name already ending in a unit (a ``_uS`` pass-through column, the
    generic ``force_N``/``conductance_S``) is kept as it is. ``quantity``: :data:`FORCE_COLUMN` or
    :data:`CONDUCTANCE_COLUMN`. Every reader here takes both styles (:data:`UNIT_SUFFIXES`)."""
    suffix, scale = ("N", 1.0) if quantity == FORCE_COLUMN else ("uS", 1e6)
    names, scaled = [], np.array(values, dtype=np.float64, copy=True)
    known = {unit for units in UNIT_SUFFIXES.values() for unit in units}
    for k, name in enumerate(columns):
        stem, sep, unit = name.rpartition("_")
        if name in (FORCE_COLUMN, CONDUCTANCE_COLUMN) or (sep and stem and unit in known):
            names.append(name)
        else:
            names.append(f"{name}_{suffix}")
            scaled[:, k] *= scale
    return names, scaled


def write_series_csv(path: str | os.PathLike, time_s: np.ndarray, columns: tuple[str, ...] | list[str],
                     values: np.ndarray, digits: int = 17) -> None:
    """Write ``time_s`` (N,) and ``values`` (N, S) under the header ``time_s,<columns>`` with full float precision
    (``digits`` significant digits for the values: 17 round-trips float64, 9 float32; time always 17)."""
    time_s = np.asarray(time_s, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64).reshape(time_s.shape[0], -1)
    if values.shape[1] != len(columns):
        raise ValueError(f"{len(columns)} column names for {values.shape[1]} columns")
    header = ",".join([TIME_COLUMN, *columns])
    if _arrow_csv is not None and digits in (9, 17):
        # Arrow's C++ writer (0.15 s against savetxt's 0.56 s, 30 MB): each number in the shortest form that reads
        # back to the same float64 (17 digits) or float32 (9 digits) — the same values savetxt's %.17g / %.9g
        # give, in fewer bytes.
        kind = np.float64 if digits == 17 else np.float32
        arrays = [_arrow.array(time_s)] + [_arrow.array(values[:, i].astype(kind)) for i in range(values.shape[1])]
        table = _arrow.Table.from_arrays(arrays, names=[f"c{i}" for i in range(len(arrays))])

        def write(handle: TextIO) -> None:
            handle.write(header + "\n")
            handle.flush()
            _arrow_csv.write_csv(table, handle.buffer, _arrow_csv.WriteOptions(include_header=False))  # type: ignore[attr-defined]

        _atomic_write(Path(path), write)
        return
    table_np = np.column_stack([time_s, values])
    fmt = ["%.17g"] + [f"%.{int(digits)}g"] * values.shape[1]
    _atomic_write(Path(path), lambda handle: np.savetxt(handle, table_np, delimiter=",", fmt=fmt,
                                                        header=header, comments=""))


def write_trial_csv(path: str | os.PathLike, time_s: np.ndarray, force_n: np.ndarray,
                    conductance_s: np.ndarray) -> None:
    """Write a calibration trial CSV (SPEC §3.1), e.g. from the rig or the synthetic generator."""
    table = np.column_stack([time_s, force_n, conductance_s]).astype(np.float64)
    header = ",".join([TIME_COLUMN, FORCE_COLUMN, CONDUCTANCE_COLUMN])
    _atomic_write(Path(path), lambda handle: np.savetxt(handle, table, delimiter=",", fmt="%.17g",
                                                        header=header, comments=""))


def write_atomically(path: str | os.PathLike, write: Callable[[TextIO], object]) -> None:
    """``write(handle)`` into a new text file at ``path``, all or nothing (see :func:`_atomic_write`); for writers
    outside this module (a recording's CSV export)."""
    _atomic_write(Path(path), write)


def _atomic_write(path: Path, write: Callable[[TextIO], object]) -> None:
    """Write through a hidden temporary in the same folder so a crash never leaves a half-written file
    (:mod:`app.core.outputs`: only a regular file is ever replaced; a device, FIFO or socket is refused).

    The file gets the permissions any new file of the user gets (0666 less the umask), or keeps those of the file
    it replaces; a failure is an ``OSError`` naming ``path`` (the user's file), never the hidden temporary one.
    """
    folder = path.parent if str(path.parent) else Path(".")
    check_output(path)
    if not folder.is_dir():
        what = f"{folder} is not a folder" if folder.exists() else f"folder {folder} does not exist"
        raise CalFileError(f"{path}: {what}")
    try:
        fd, temp_path = create_temporary(path, ".tmp")
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write {path}: {exc.strerror or exc}") from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as handle:
            write(handle)
        move_into_place(temp_path, path)
    except OutputPathError:
        temp_path.unlink(missing_ok=True)
        raise
    except OSError as exc:
        temp_path.unlink(missing_ok=True)
        raise OSError(exc.errno, f"cannot write {path}: {exc.strerror or exc}") from None
    except BaseException:
        temp_path.unlink(missing_ok=True)
        raise


# --------------------------------------------------------------------------------------------------------- JSON


# The largest calibration file read (a calibration of 1024 sensors with their history is a few MB): json reads the
# whole file into memory, so a larger one is refused before it is read.
MAX_JSON_BYTES = 64_000_000


def _load_json(path: str | os.PathLike) -> tuple[Path, Any]:
    file = Path(path)
    return file, read_json_file(file, "calibration file", CalFileError, MAX_JSON_BYTES, not_found=": no such file")


def _check_format(file: Path, document: Any) -> None:
    if not isinstance(document, dict):
        raise CalFileError(f"{file}: expected a JSON object with format '{CAL_FORMAT}'")
    if document.get("format") != CAL_FORMAT:
        raise CalFileError(
            f"{file}: unknown format {document.get('format')!r}: expected '{CAL_FORMAT}' (is this a calibration file?)"
        )
    if document.get("version") != CAL_VERSION:
        raise CalFileError(
            f"{file}: unsupported calibration version {document.get('version')!r}: this sensnake reads version "
            f"{CAL_VERSION}; upgrade sensnake or re-run 'sensnake fit'"
        )
    if not isinstance(document.get("sensors", {}), dict):
        raise CalFileError(f"{file}: 'sensors' must be an object keyed by sensor name")


def read_calibration(path: str | os.PathLike) -> dict[str, Any]:
    """Read and check a calibration JSON (SPEC §3.3); unknown ``format``/``version`` is refused."""
    file, document = _load_json(path)
    _check_format(file, document)
    document.setdefault("sensors", {})
    return document


def physics_from_calibration(document: dict[str, Any], source: str) -> PhysicsConstants:
    """The calibration's resistance–strain constants; a file without them is refused (no hidden default)."""
    if "physics" not in document:
        raise CalFileError(f"{source}: no 'physics' section: re-run 'sensnake fit' with --physics FILE.json")
    try:
        return PhysicsConstants.from_dict(document["physics"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CalFileError(f"{source}: bad 'physics' section: {exc}") from exc


def read_physics(path: str | os.PathLike) -> PhysicsConstants:
    """Read ``--physics FILE.json``: the SPEC §3.3 physics keys at the top level or under ``physics``.

    A file that names a ``format`` or ``version`` is a calibration file: one of another format or version is refused
    (SPEC §3.3: readers reject what they do not know) and its ``physics`` section is read. A bare object of physics
    keys has neither and is read as it is."""
    file, document = _load_json(path)
    if not isinstance(document, dict):
        raise CalFileError(f"{file}: expected a JSON object with the physics keys")
    if "format" in document or "version" in document:
        _check_format(file, document)
        return physics_from_calibration(document, str(file))
    try:
        return PhysicsConstants.from_dict(document)
    except (KeyError, TypeError, ValueError) as exc:
        raise CalFileError(f"{file}: {exc}") from exc


def sensor_entry(document: dict[str, Any], name: str, model: str, source: str) -> dict[str, Any]:
    """The sensor ``name``'s entry, checked to hold ``area_m2`` and the ``model`` section with finite numbers."""
    sensors = document.get("sensors", {})
    if name not in sensors:
        known = ", ".join(sorted(sensors)) or "none"
        raise CalFileError(f"{source}: no calibration for sensor '{name}' (calibrated sensors: {known})")
    entry = sensors[name]
    keys = {"linear": ("m_S_per_N", "d_S"), "sls": ("E0_Pa", "E1_Pa", "mu1_Pa_s")}[model]
    section = entry.get(model) if isinstance(entry, dict) else None
    if not isinstance(section, dict):
        raise CalFileError(f"{source}: sensor '{name}' has no '{model}' model: re-run 'sensnake fit'")
    for key in keys:
        value = section.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise CalFileError(f"{source}: sensor '{name}' {model}.{key} is {value!r}, expected a finite number")
        if model == "sls" and not value > 0:  # a stiffness or a viscosity: the model has no meaning at or below 0
            raise CalFileError(f"{source}: sensor '{name}' {model}.{key} is {value!r}, expected a positive number")
    if model == "sls":
        area = entry.get("area_m2")
        if isinstance(area, bool) or not isinstance(area, (int, float)) or not (area > 0 and math.isfinite(area)):
            raise CalFileError(f"{source}: sensor '{name}' area_m2 is {area!r}, expected a positive number")
    return entry


READOUT_KEYS = ("r_c_ohm", "v_ref_v", "v_supply_v")


def readout_of(board: Any) -> dict[str, float]:
    """The readout circuit of a :class:`devices.config.BoardConfig` as stored with a sensor's calibration."""
    return {key: float(getattr(board, key)) for key in READOUT_KEYS}


def sensor_readout(document: dict[str, Any], names: Sequence[str], path: str | os.PathLike = "") -> dict | None:
    """The readout circuit ``names`` were calibrated with (their entries' ``readout``), None when none of them says;
    CalFileError when they say different ones (the file mixes readouts: pass --config)."""
    found = {name: document["sensors"][name].get("readout") for name in names if name in document["sensors"]}
    said = {name: r for name, r in found.items() if isinstance(r, dict)}
    if not said:
        return None
    distinct = {tuple(sorted(r.items())) for r in said.values()}
    if len(distinct) > 1:
        which = ", ".join(f"{name}: R_C {readout.get('r_c_ohm')} Ω" for name, readout in said.items())
        raise CalFileError(f"{path}: its sensors were calibrated with different readout circuits ({which}): "
                           "estimate them separately, or give --config for one readout")
    readout = next(iter(said.values()))
    for key in READOUT_KEYS:
        value = readout.get(key)
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
            raise CalFileError(f"{path}: readout.{key} = {value!r} must be a positive number")
    return readout


def update_calibration(path: str | os.PathLike, sensor_name: str, entry: dict[str, Any],
                       physics: PhysicsConstants, readout: dict[str, float] | None = None) -> dict[str, Any]:
    """Create ``path`` or update it in place: set ``sensors[sensor_name] = entry`` (with ``readout``, the circuit
    the sensor was calibrated on, when given) and ``physics``; other sensors and unknown keys are kept. An existing
    file of another format/version is refused, never overwritten."""
    if readout is not None:
        entry = {**entry, "readout": dict(readout)}
    file = Path(path)
    if file.exists():
        document = read_calibration(file)
        old_physics = document.get("physics")
        if old_physics is not None and document["sensors"] and old_physics != physics.to_dict():
            others = sorted(set(document["sensors"]) - {sensor_name})
            if others:
                raise CalFileError(
                    f"{file}: its physics constants differ from the ones used for this fit, and sensors "
                    f"{', '.join(others)} were fitted with them: use --physics {file} or write to a new file"
                )
    else:
        document = {"format": CAL_FORMAT, "version": CAL_VERSION}
    document["physics"] = physics.to_dict()
    document.setdefault("sensors", {})[sensor_name] = entry
    def write(handle: TextIO) -> None:
        json.dump(_jsonable(document), handle, indent=2, allow_nan=False)
        handle.write("\n")

    _atomic_write(file, write)
    return document


def _jsonable(value: Any) -> Any:
    """numpy scalars → Python floats; NaN/inf → None (JSON has neither)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        number = float(value)
        return number if math.isfinite(number) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value
