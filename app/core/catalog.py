"""The run catalog: every recording's run metadata in one embedded SQLite database, to find runs without opening them.

The files stay the truth. The catalog (``catalog.sqlite`` in the data folder, :func:`app.core.user_folders.
data_dir`; WAL journal, so a reader never waits for a writer) only remembers what each recording's run documents
(:mod:`app.core.run_documents`) and groups say, keyed by the file's absolute path and checked against the file's
size and modification time: a listing first reads again every file under its folder that is new or changed since it
was indexed, and forgets those that are gone (:meth:`Catalog.sync`). So a catalog that is deleted, stale or corrupt
costs one re-read, never a wrong answer: a database SQLite cannot read is moved aside (``catalog.sqlite.corrupt``)
and rebuilt; one that cannot be written at all is replaced by one in memory for that command.

Recordings are indexed when their writer has closed them (:func:`finish_run`, called on the writer's thread once the
file is complete): never on the data
path, and a catalog that is busy or broken is skipped silently (the next listing reads the file). Recordings from
before the run documents are indexed with what can be read: the ``started`` attribute, the physics lab's ``/sim``
attributes (scene, outcome, validity), ``/control``'s controller and the plan line the physics lab writes at the
top of the config text.

One :class:`Catalog` per thread (sqlite3 connections are not shared between threads).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import sqlite3
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import h5py

from app.core.run_documents import RUN_START, RUN_STOP, parse_document, write_run_stop
from app.core.user_folders import data_dir

CATALOG_FILE = "catalog.sqlite"
SCHEMA_VERSION = 1
BUSY_TIMEOUT_S = 5.0  # a command waits this long for another writer of the catalog
QUIET_BUSY_TIMEOUT_S = 0.2  # a recording's writer thread gives up this soon (the next listing reads the file)
RECORDING_SUFFIXES = (".h5", ".hdf5")


@dataclass(frozen=True)
class Column:
    name: str
    sql_type: str  # TEXT, REAL, INTEGER
    aliases: tuple[str, ...] = ()


# What the catalog holds per recording, in the order listings show it.
COLUMNS: tuple[Column, ...] = (
    Column("path", "TEXT", ("file",)), Column("started", "TEXT"), Column("plan_name", "TEXT", ("plan",)),
    Column("scene", "TEXT"), Column("shape", "TEXT"), Column("mode", "TEXT"), Column("speed_rad_s", "REAL", ("speed",)),
    Column("controller", "TEXT"), Column("tail_load_n", "REAL", ("tail_load",)), Column("seed", "INTEGER"),
    Column("trial", "INTEGER"), Column("series_uid", "TEXT", ("series",)), Column("outcome", "TEXT"),
    Column("exit_status", "TEXT", ("status",)), Column("reason", "TEXT"), Column("valid", "INTEGER"),
    Column("duration_s", "REAL", ("duration",)), Column("n_samples", "INTEGER"), Column("groups", "TEXT"),
    Column("note", "TEXT"), Column("uid", "TEXT"), Column("calibration_hash", "TEXT"),
    Column("config_hash", "TEXT"), Column("scene_hash", "TEXT"), Column("app_version", "TEXT"),
    Column("problem", "TEXT"),
)
_HIDDEN = ("folder", "mtime_ns", "size", "start_epoch", "indexed_at")
_BY_NAME = {c.name: c for c in COLUMNS} | {a: c for c in COLUMNS for a in c.aliases}
_LEGACY_PLAN = re.compile(r"^# sensnake (experiment \w+)(?::\s*scene ([^,]+), mode (\w+), controller (\w+), "
                          r"tail load ([0-9.eE+-]+) N)?")
_SEED_SUFFIX = re.compile(r" \(seed \d+\)$")


def catalog_path() -> Path:
    return data_dir() / CATALOG_FILE


# -- reading one recording -------------------------------------------------------------------------------------------
def _text(value: Any) -> str:
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)


def _epoch(iso: str) -> float | None:
    try:
        moment = datetime.fromisoformat(iso.replace("Z", "+00:00"))
        if moment.tzinfo is None:
            moment = moment.astimezone()  # a naive time is the machine's local time
        return moment.timestamp()
    except (ValueError, OverflowError, OSError):  # not a time, or one no clock holds (year 1 in local time)
        return None


def read_entry(path: str | Path) -> dict[str, Any]:
    """What the catalog holds of one recording (see :data:`COLUMNS`); a file that cannot be read gets an entry with
    ``problem`` saying why (it is listed, never refused)."""
    path = Path(path).resolve()
    stat = path.stat()
    entry: dict[str, Any] = {"path": str(path), "folder": str(path.parent), "mtime_ns": stat.st_mtime_ns,
                             "size": stat.st_size, "indexed_at": time.time()}
    try:
        with h5py.File(path, "r", locking=False) as f:
            _read_h5(f, entry)
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as exc:
        entry["problem"] = f"unreadable: {' '.join(str(exc).split())[:160]}"
    return entry


def _read_h5(f: h5py.File, entry: dict[str, Any]) -> None:
    if _text(f.attrs.get("format", "")) != "sensnake-recording":
        entry["problem"] = "not a SenSnake recording"
        return
    started = _text(f.attrs.get("started", ""))
    entry["started"] = started or None
    entry["start_epoch"] = _epoch(started) if started else None
    duration = f.attrs.get("duration_s")
    entry["duration_s"] = float(duration) if duration is not None else None
    if "daq" in f and "time_s" in f["daq"]:
        entry["n_samples"] = int(f["daq/time_s"].shape[0])
        if entry["duration_s"] is None and entry["n_samples"]:
            entry["duration_s"] = float(f["daq/time_s"][-1])
    entry["groups"] = " ".join(name for name in ("daq", "robot", "forces", "control", "sim", "mocap") if name in f)
    _legacy(f, entry)  # what older files say; the run documents below override it
    start, stop = parse_document(f.attrs.get(RUN_START)), parse_document(f.attrs.get(RUN_STOP))
    if start is not None:
        condition = start.get("condition") or {}
        for key in ("scene", "shape", "mode", "speed_rad_s", "controller", "tail_load_n", "calibration_hash",
                    "config_hash", "scene_hash"):
            if condition.get(key) is not None:
                entry[key] = condition[key]
        for key in ("uid", "plan_name", "seed", "trial", "series_uid", "note", "app_version"):
            if start.get(key) is not None:
                entry[key] = start[key]
        if isinstance(start.get("time"), (int, float)) and entry.get("start_epoch") is None:
            # the file's "started" (what the listing shows, and what --since is compared with) when it has one:
            # the document's time is when run_start was written, up to a second earlier, and a --since copied
            # from the listing left the run out
            entry["start_epoch"] = float(start["time"])
    if stop is not None:
        for key in ("exit_status", "reason", "outcome"):
            if stop.get(key) is not None:
                entry[key] = stop[key]
        if stop.get("note"):  # the operator's note on a robot trial's outcome, after the run's own note
            entry["note"] = "; ".join(str(n) for n in (entry.get("note"), stop["note"]) if n)
    elif start is not None:
        entry["exit_status"] = "incomplete"  # a run_start without its run_stop: the run was cut short
    if entry.get("outcome") == "invalid":
        entry["valid"] = 0


def _legacy(f: h5py.File, entry: dict[str, Any]) -> None:
    config = _text(f.attrs.get("config", ""))
    match = _LEGACY_PLAN.match(config)
    if match:
        entry["plan_name"] = match.group(1)
        if match.group(2):
            entry.update(scene=match.group(2).strip(), mode=match.group(3), controller=match.group(4),
                         tail_load_n=float(match.group(5)))
    if "sim" in f:
        sim = f["sim"].attrs
        if "scene_name" in sim:
            entry["scene"] = _SEED_SUFFIX.sub("", _text(sim["scene_name"]))
        if "valid" in sim:
            entry["valid"] = int(sim["valid"])
        if "outcome" in sim:
            entry["outcome"] = _text(sim["outcome"])
        if not int(sim.get("valid", 1)):
            entry["reason"] = _text(sim.get("invalid_reason", ""))
        entry.setdefault("controller", "feedforward")
    if "control" in f and "controller" in f["control"].attrs:
        entry["controller"] = _text(f["control"].attrs["controller"])


# -- the database ----------------------------------------------------------------------------------------------------
def _plain_value(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, (dict, list)):
        return json.dumps(value)
    return value


class Catalog:
    """The catalog database (see the module docstring). ``path`` None: the data folder's; ``":memory:"`` for one
    that lives as long as the object."""

    def __init__(self, path: str | Path | None = None, busy_timeout_s: float = BUSY_TIMEOUT_S) -> None:
        self.path = catalog_path() if path is None else path
        self.busy_timeout_s = busy_timeout_s
        self.note = ""  # what happened to the database on opening (rebuilt, in memory), for the user
        self.unreadable: list[tuple[Path, str]] = []  # the folders the last sync could not list, and why
        self._db = self._open()

    # -- opening, and rebuilding what cannot be read ----------------------------------------------------------------
    def _open(self) -> sqlite3.Connection:
        if str(self.path) == ":memory:":
            return self._prepare(sqlite3.connect(":memory:"))
        path = Path(self.path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            return self._prepare(sqlite3.connect(path, timeout=self.busy_timeout_s))
        except sqlite3.DatabaseError as exc:
            if isinstance(exc, sqlite3.OperationalError) and "locked" in str(exc):
                raise
            with contextlib.suppress(OSError):
                os.replace(path, path.with_name(path.name + ".corrupt"))
                for suffix in ("-wal", "-shm"):
                    with contextlib.suppress(OSError):
                        path.with_name(path.name + suffix).unlink()
                self.note = f"the catalog {path} could not be read ({exc}); moved aside and rebuilt from the files"
                return self._prepare(sqlite3.connect(path, timeout=self.busy_timeout_s))
        except OSError:
            pass
        self.note = f"the catalog {path} cannot be written; using one in memory for this command"
        return self._prepare(sqlite3.connect(":memory:"))

    def _prepare(self, db: sqlite3.Connection) -> sqlite3.Connection:
        try:
            db.execute(f"PRAGMA busy_timeout = {int(self.busy_timeout_s * 1000)}")
            db.execute("PRAGMA journal_mode = WAL")
            db.execute("PRAGMA synchronous = NORMAL")
            version = db.execute("PRAGMA user_version").fetchone()[0]
            if version != SCHEMA_VERSION:  # a catalog of another layout: rebuilt, the files are the truth
                db.execute("DROP TABLE IF EXISTS runs")
                columns = ", ".join(f"{c.name} {c.sql_type}" for c in COLUMNS if c.name != "path")
                db.execute(f"CREATE TABLE runs (path TEXT PRIMARY KEY, folder TEXT, mtime_ns INTEGER, size INTEGER, "
                           f"start_epoch REAL, indexed_at REAL, {columns})")
                db.execute("CREATE INDEX runs_folder ON runs (folder)")
                db.execute("CREATE INDEX runs_scene ON runs (scene)")
                db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
                db.commit()
            db.execute("SELECT count(*) FROM runs").fetchone()
        except sqlite3.DatabaseError:
            db.close()
            raise
        return db

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> Catalog:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- writing ---------------------------------------------------------------------------------------------------
    def put(self, entries: Iterable[dict[str, Any]]) -> int:
        names = ["path", *_HIDDEN, *(c.name for c in COLUMNS if c.name != "path")]
        rows = [tuple(_plain_value(e.get(n)) for n in names) for e in entries]
        with self._db:
            self._db.executemany(f"INSERT OR REPLACE INTO runs ({', '.join(names)}) VALUES "
                                 f"({', '.join('?' * len(names))})", rows)
        return len(rows)

    def index(self, path: str | Path) -> dict[str, Any]:
        entry = read_entry(path)
        self.put([entry])
        return entry

    def forget(self, paths: Sequence[str]) -> None:
        with self._db:
            self._db.executemany("DELETE FROM runs WHERE path = ?", [(p,) for p in paths])

    def sync(self, folder: str | Path, force: bool = False, cancelled: Callable[[], bool] | None = None,
             progress: Callable[[int, int], None] | None = None) -> tuple[int, int]:
        """Bring the catalog in line with the recordings under ``folder`` (recursively): new or changed files read
        (every file with ``force``), gone ones forgotten. Returns (read, forgotten). ``cancelled()`` (optional) is
        asked between files: True stops the reading there (what was read is kept; the next sync reads the rest).
        ``progress(done, total)`` (optional) is told before each file to read and once after the last."""
        root = Path(folder).resolve()
        known = {row[0]: (row[1], row[2]) for row in self._db.execute(
            "SELECT path, mtime_ns, size FROM runs WHERE path >= ? AND path < ?", _prefix_range(root))}
        changed, seen = [], set()
        self.unreadable = []
        for path, stat in _recordings_under(root, self.unreadable):
            key = str(path)
            seen.add(key)
            if force or known.get(key) != (stat.st_mtime_ns, stat.st_size):
                changed.append(path)
        entries: list[dict[str, Any]] = []
        for done, path in enumerate(changed):
            if cancelled is not None and cancelled():
                self.put(entries)
                return len(entries), 0
            if progress is not None:
                progress(done, len(changed))
            with contextlib.suppress(OSError):  # gone between the walk and the read: forgotten below next time
                entries.append(read_entry(path))
        if progress is not None and changed:
            progress(len(changed), len(changed))
        self.put(entries)
        # a folder that could not be listed hides its recordings, it does not remove them: they are not forgotten
        blocked = tuple(str(folder).rstrip(os.sep) + os.sep for folder, _ in self.unreadable)
        gone = [p for p in known if p not in seen and not p.startswith(blocked)]
        self.forget(gone)
        return len(entries), len(gone)

    def prune(self) -> int:
        """Forget the catalogued recordings whose file is gone (anywhere). Returns how many."""
        gone = [p for (p,) in self._db.execute("SELECT path FROM runs") if not os.path.exists(p)]
        self.forget(gone)
        return len(gone)

    # -- reading ---------------------------------------------------------------------------------------------------
    def query(self, folder: str | Path | None = None, where: Sequence[str] = (), since: str | None = None
              ) -> list[dict[str, Any]]:
        """The catalogued recordings (under ``folder`` when given), oldest first, matching every ``KEY=VALUE`` of
        ``where`` (KEY a column of :data:`COLUMNS` or an alias: ``plan``, ``speed``, ``status``, …) and started on
        or after ``since`` (a date or ISO 8601 time; without a zone, the machine's local time)."""
        clauses: list[str] = []
        values: list[Any] = []
        if folder is not None:
            clauses.append("path >= ? AND path < ?")
            values += list(_prefix_range(Path(folder).resolve()))
        for condition in where:
            column, value = parse_where(condition)
            if value == "":
                clauses.append(f"({column.name} IS NULL OR {column.name} = '')")
            elif column.sql_type == "TEXT":
                clauses.append(f"{column.name} = ?")
                values.append(value)
            else:
                clauses.append(f"abs({column.name} - ?) <= 1e-9 * max(1.0, abs(?))")
                values += [float(value)] * 2
        if since is not None:
            clauses.append("start_epoch >= ?")
            values.append(parse_since(since))
        sql = "SELECT * FROM runs" + (" WHERE " + " AND ".join(clauses) if clauses else "") + \
            " ORDER BY start_epoch, path"
        cursor = self._db.execute(sql, values)
        names = [d[0] for d in cursor.description]
        return [dict(zip(names, row)) for row in cursor]

    def get(self, path: str | Path) -> dict[str, Any] | None:
        cursor = self._db.execute("SELECT * FROM runs WHERE path = ?", (str(Path(path).resolve()),))
        row = cursor.fetchone()
        return None if row is None else dict(zip([d[0] for d in cursor.description], row))

    def count(self) -> int:
        return int(self._db.execute("SELECT count(*) FROM runs").fetchone()[0])


def parse_where(condition: str) -> tuple[Column, str]:
    """``KEY=VALUE`` → (the column, VALUE); ValueError naming the keys there are."""
    key, sep, value = condition.partition("=")
    column = _BY_NAME.get(key.strip())
    if not sep or column is None:
        known = ", ".join(c.name for c in COLUMNS)
        raise ValueError(f"--where {condition!r}: expected KEY=VALUE with KEY one of {known}")
    value = value.strip()
    if column.sql_type != "TEXT" and value:
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"--where {condition!r}: {column.name} is a number") from None
        if not math.isfinite(number):  # inf matched every run (|x − inf| ≤ 1e-9 · inf)
            raise ValueError(f"--where {condition!r}: {column.name} is a finite number")
    if column.name == "path" and value:
        value = str(Path(value).resolve())
    return column, value


def parse_since(text: str) -> float:
    epoch = _epoch(text.strip())
    if epoch is None:
        raise ValueError(f"--since {text!r}: expected a date (2026-12-01) or an ISO 8601 time")
    return epoch


def _prefix_range(root: Path) -> tuple[str, str]:
    """The path range of everything under ``root`` (``root/`` ≤ path < ``root0``: '0' follows '/')."""
    prefix = str(root).rstrip(os.sep) + os.sep
    return prefix, prefix[:-1] + chr(ord(os.sep) + 1)


def _recordings_under(root: Path, unreadable: list[tuple[Path, str]]) -> Iterator[tuple[Path, os.stat_result]]:
    """Every recording file under ``root`` (recursively; hidden files and folders — writers' temporaries — left out).
    A folder that cannot be listed is added to ``unreadable`` with the reason."""
    stack = [root]
    while stack:
        folder = stack.pop()
        try:
            entries = list(os.scandir(folder))
        except OSError as exc:
            unreadable.append((folder, exc.strerror or type(exc).__name__))
            continue
        for entry in entries:
            if entry.name.startswith("."):
                continue
            try:
                if entry.is_dir(follow_symlinks=False):
                    stack.append(Path(entry.path))
                elif entry.name.lower().endswith(RECORDING_SUFFIXES) and entry.is_file():
                    yield Path(entry.path), entry.stat()
            except OSError:
                continue


def unreadable_words(unreadable: list[tuple[Path, str]]) -> str:
    """One line for the folders a sync could not list ("" when none)."""
    if not unreadable:
        return ""
    shown = "; ".join(f"{folder} ({why})" for folder, why in unreadable[:3])
    more = f" and {len(unreadable) - 3} more" if len(unreadable) > 3 else ""
    return (f"{len(unreadable)} folder(s) could not be read, their recordings are not listed: {shown}{more}")


def index_quietly(path: str | Path) -> None:
    """Index one closed recording into the data folder's catalog, giving up at once if it is busy or broken (the
    file is the truth; the next listing reads it). For writer threads: never raises."""
    with contextlib.suppress(sqlite3.Error, OSError, ValueError), Catalog(busy_timeout_s=QUIET_BUSY_TIMEOUT_S) as c:
        c.index(path)


def finish_run(path: str | Path, start: Mapping[str, Any] | None, exit_status: str, reason: str = "",
               outcome: str | None = None) -> None:
    """What the owner of a run does once its file is closed: its ``run_stop`` written
    (:func:`app.core.run_documents.write_run_stop`), then the catalog told (:func:`index_quietly`: a catalog that
    is busy or broken is skipped; the file is the truth and the next ``runs list`` reads it). A file that cannot be
    written keeps what it has (no ``run_stop``: read as cut short). Never raises an OSError or a catalog's error."""
    with contextlib.suppress(OSError):
        write_run_stop(path, start, exit_status, reason, outcome)
    index_quietly(path)
