"""A recording's run documents: what was run, under which condition, and how it ended (bluesky's RunStart/RunStop).

Every recording the app or the command line writes carries two JSON texts as root attributes (SPEC §3.5 extension,
docs/SPEC_EXTENSIONS.md):

``run_start`` — written when the file is created::

    {"uid": "…", "time": 1795000000.0, "plan_name": "experiment run",
     "condition": {"scene": "paper_obstacle", "scene_hash": "…", "shape": "settled", "mode": "follow",
                   "speed_rad_s": 0.034, "controller": "feedforward", "gains": null, "tail_load_n": 0.0,
                   "calibration_hash": "…", "config_hash": "…"},
     "seed": 3, "trial": 2, "series_uid": "…", "note": "", "app_version": "0.1.0"}

``trial``/``series_uid`` only for a run in a series; ``seed`` only for a simulated run. A key of the condition the
writer cannot know (a live recording does not know what the Gait tab plays) is null, never guessed.

``run_stop`` — written once the file is complete::

    {"uid": "…", "time": …, "run_start": "<run_start uid>", "exit_status": "success"|"abort"|"fail",
     "reason": "…", "outcome": "traversed"|"not traversed"|"undecided"|"invalid"|null}

A robot trial's outcome is the operator's (``traversed``, ``failed``, ``aborted``), with the operator's ``note`` on
it (the key only when there is one).

A file with a ``run_start`` and no ``run_stop`` is a run that was cut short (a crash, a killed process): bluesky's
reading of a run without its stop document. Readers ignore what they do not know.

Qt-free; any thread (no state).
"""

from __future__ import annotations

import hashlib
import json
import math
import time
import uuid
from collections.abc import Mapping
from dataclasses import asdict, is_dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

import h5py
import numpy as np

RUN_START = "run_start"
RUN_STOP = "run_stop"
EXIT_STATUSES = ("success", "abort", "fail")
CONDITION_KEYS = ("scene", "scene_hash", "shape", "mode", "speed_rad_s", "controller", "gains", "tail_load_n",
                  "calibration_hash", "config_hash")
# Keys that may differ between trials of one condition: each simulated trial has its own seeded sensors (so its own
# true calibration); a series on the robot may be re-calibrated between trials without changing what was run.
NOT_THE_CONDITION = ("calibration_hash",)
HASH_CHARS = 16  # 64 bits of SHA-256: enough to tell two texts apart, short enough to read in a table


def text_hash(text: str | bytes | None) -> str | None:
    """The first :data:`HASH_CHARS` hex digits of the SHA-256 of ``text`` (None for None or empty)."""
    if not text:
        return None
    data = text.encode("utf-8") if isinstance(text, str) else bytes(text)
    return hashlib.sha256(data).hexdigest()[:HASH_CHARS]


def app_version() -> str:
    try:
        return metadata.version("sensnake-studio")
    except metadata.PackageNotFoundError:
        return "unknown"


def _plain(value: Any) -> Any:
    """``value`` as JSON can hold it: dataclasses as dicts, NaN and ±inf as null, numpy scalars as numbers."""
    if is_dataclass(value) and not isinstance(value, type):
        return _plain(asdict(value))
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "item") and callable(value.item):  # a numpy scalar
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def condition(*, scene: str | None = None, scene_text: str | None = None, shape: str | None = None,
              mode: str | None = None, speed_rad_s: float | None = None, controller: str | None = None,
              gains: Any = None, tail_load_n: float | None = None, calibration_json: str | None = None,
              config_text: str | None = None) -> dict[str, Any]:
    """The condition of a run: what must be the same for two runs to be trials of one experiment. Units in the
    keys; the calibration and the lab config by their hashes (:func:`text_hash`); NaN reads as unknown (null)."""
    return _plain({"scene": scene, "scene_hash": text_hash(scene_text), "shape": shape, "mode": mode,
                   "speed_rad_s": None if speed_rad_s is None else float(speed_rad_s), "controller": controller,
                   "gains": gains, "tail_load_n": None if tail_load_n is None else float(tail_load_n),
                   "calibration_hash": text_hash(calibration_json), "config_hash": text_hash(config_text)})


def run_start_document(plan_name: str, run_condition: Mapping[str, Any], *, seed: int | None = None,
                       trial: int | None = None, series_uid: str | None = None, note: str = "",
                       when: float | None = None) -> dict[str, Any]:
    """A RunStart document (see the module docstring); ``when``: Unix time, default now."""
    document: dict[str, Any] = {"uid": str(uuid.uuid4()), "time": time.time() if when is None else float(when),
                                "plan_name": plan_name, "condition": _plain(dict(run_condition))}
    if seed is not None:
        document["seed"] = int(seed)
    if trial is not None:
        document["trial"] = int(trial)
    if series_uid is not None:
        document["series_uid"] = str(series_uid)
    document["note"] = note
    document["app_version"] = app_version()
    return document


def with_metadata(document: Mapping[str, Any], md: Mapping[str, Any] | None) -> dict[str, Any]:
    """``document`` with a caller's metadata added (bluesky's ``md``: ``trial``, ``series_uid``, ``note``,
    ``plan_name``); the condition and the uid are the document's own and never replaced."""
    merged = dict(document)
    for key, value in (md or {}).items():
        if key not in ("uid", "time", "condition") and value is not None:
            merged[key] = _plain(value)
    return merged


def run_stop_document(start: Mapping[str, Any] | None, exit_status: str, reason: str = "",
                      outcome: str | None = None, when: float | None = None, note: str | None = None
                      ) -> dict[str, Any]:
    """A RunStop document closing ``start`` (None: a file without a start document); ``note``: the operator's note
    on the outcome (a robot trial's), only when given."""
    if exit_status not in EXIT_STATUSES:
        raise ValueError(f"exit_status must be one of {', '.join(EXIT_STATUSES)}, got {exit_status!r}")
    document = {"uid": str(uuid.uuid4()), "time": time.time() if when is None else float(when),
                "run_start": None if start is None else start.get("uid"), "exit_status": exit_status,
                "reason": reason, "outcome": outcome}
    if note:
        document["note"] = note
    return document


def document_text(document: Mapping[str, Any]) -> str:
    """The JSON text stored as the attribute (NaN never written: JSON has none)."""
    return json.dumps(_plain(document), sort_keys=False, allow_nan=False)


def parse_document(value: Any) -> dict[str, Any] | None:
    """A stored document (an HDF5 attribute: str or bytes), or None when it is absent or not a JSON object."""
    if value is None:
        return None
    text = value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)
    try:
        document = json.loads(text)
    except ValueError:
        return None
    return document if isinstance(document, dict) else None


def read_documents(path: str | Path) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """(run_start, run_stop) of a recording; None for each it does not have. Raises OSError for an unreadable file."""
    with h5py.File(path, "r", locking=False) as f:
        return parse_document(f.attrs.get(RUN_START)), parse_document(f.attrs.get(RUN_STOP))


RUN_STOP_RESERVED_BYTES = 4096  # room kept for the run_stop document when the file is made


def reserve_run_stop(attrs: Any) -> None:
    """Make room for the ``run_stop`` document among a new file's root attributes, empty (read as no run_stop: a
    run cut short). Writing it later in that room changes no object header: a new attribute appended to a finished
    file moves the root group's header to the file's end, where a truncated copy loses it and with it the whole
    recording (``sensnake repair`` then salvages nothing)."""
    attrs.create(RUN_STOP, np.bytes_(b""), dtype=h5py.string_dtype("utf-8", RUN_STOP_RESERVED_BYTES))


def write_run_stop(path: str | Path, start: Mapping[str, Any] | None, exit_status: str, reason: str = "",
                   outcome: str | None = None, note: str | None = None) -> dict[str, Any]:
    """Close a finished recording's run: write its ``run_stop`` (after the file is complete; the writer is closed),
    into the room :func:`reserve_run_stop` kept when it has one (a long reason is shortened to fit), else as a new
    attribute. Returns the document. Raises OSError when the file cannot be opened for writing."""
    document = run_stop_document(start, exit_status, reason, outcome, note=note)
    text = document_text(document)
    with h5py.File(path, "a", locking=False) as f:
        reserved = f.attrs.get_id(RUN_STOP).dtype.itemsize if RUN_STOP in f.attrs else 0
        if reserved:
            while len(text.encode("utf-8")) > reserved:  # the longer of the reason and the note is shortened
                key = max(("reason", "note"), key=lambda name: len(str(document.get(name) or "")))
                value = str(document.get(key) or "")
                if len(value) <= 1:
                    break
                document[key] = value[: max(len(value) // 2 - 1, 0)] + "…"
                text = document_text(document)
            f.attrs.modify(RUN_STOP, np.bytes_(text.encode("utf-8")))
        else:
            f.attrs[RUN_STOP] = text
    return document


def condition_differences(first: Mapping[str, Any] | None, other: Mapping[str, Any] | None,
                          ignore: tuple[str, ...] = NOT_THE_CONDITION) -> list[str]:
    """The condition keys two runs differ in, each as ``key a ≠ b`` (the ``ignore`` keys left out); a run whose
    condition is unknown (no run_start) differs in nothing that can be said."""
    if not first or not other:
        return []
    keys = [k for k in dict.fromkeys([*first, *other]) if k not in ignore]
    return [f"{key} {_show(first.get(key))} ≠ {_show(other.get(key))}" for key in keys
            if first.get(key) != other.get(key)]


def _show(value: Any) -> str:
    return "none" if value is None else json.dumps(value) if isinstance(value, (dict, list)) else str(value)


def live_run_start(config_text: str, calibration_json: str | None, plan_name: str = "record",
                   note: str = "") -> dict[str, Any]:
    """The RunStart of a live recording (``sensnake record``, the Forces tab): its condition is what a recording
    knows — the lab config and the calibration in force; what was played is not its to say (null)."""
    return run_start_document(plan_name, condition(calibration_json=calibration_json, config_text=config_text),
                              note=note)


def with_calibration(document: Mapping[str, Any], calibration_json: str | None) -> dict[str, Any]:
    """``document`` with its condition's ``calibration_hash`` set (a plan learns its calibration when it starts)."""
    merged = dict(document)
    merged["condition"] = {**dict(document.get("condition") or {}), "calibration_hash": text_hash(calibration_json)}
    return merged


def carry_documents(source: str | Path, copy: str | Path, salvaged: str = "") -> None:
    """Give a copy of a recording (``sensnake repair``'s) the source's run documents: its ``run_start`` as it was,
    its ``run_stop`` when it had one; a run cut short (no ``run_stop``) and salvaged gets one saying so
    (``fail``, ``salvaged``: what was recovered). A source whose documents cannot be read leaves the copy without."""
    try:
        start, stop = read_documents(source)
    except OSError:
        return
    if start is None:
        return
    with h5py.File(copy, "a", locking=False) as f:
        f.attrs[RUN_START] = document_text(start)
        if stop is None and salvaged:
            stop = run_stop_document(start, "fail", f"cut short; salvaged by sensnake repair: {salvaged}")
        if stop is not None:
            f.attrs[RUN_STOP] = document_text(stop)
