"""Experiment sweeps: scenes × controllers × gains × tail loads × seeds, each a run of :func:`app.core.experiment.
run_experiment` in its own process, one recording per run, a ``summary.csv`` and a figure (``sensnake experiment
sweep SWEEP.toml --out DIR``).

A sweep file (TOML; unknown keys refused, naming the key)::

    scenes = ["paper_obstacle", "step"]          # scene files or built-in names
    controllers = ["feedforward", "feedback"]
    tail_loads_n = [0.0, 2.0, 4.0]
    seeds = [0, 1, 2]                              # seed 0: the scene as written; others vary start and friction
    seconds = 60.0                                 # time limit of the play
    speed_rad_s = 0.1
    settle_s = 6.0
    mode = "follow"
    repeat = 1                                     # follow-the-leader passes per run
    rest_cap_s = 30.0                              # how long a run waits after the motion for the body to rest
    ideal_sensing = false                          # true: the controller reads the sensors' true calibration
    [[gains]]                                      # feedback gain sets (default: one, the law's defaults)
    push_gain = 0.1
    [[gains]]
    push_gain = 0.3

Each row of ``summary.csv``: scene, controller, gains (the set's index and its JSON), tail load, seed, traversed
(the tail point passed the far edge of the last obstacle within the limit), time to traverse, advance of the body's
centroid, overload events, peak current, coefficient of variation of the bottom forces on the obstacle's front face
(:func:`app.core.experiment.front_face_cv`), wall time, the recording's file name, and when the body first lost the
ground and first rolled onto its side, how far its centroid had crawled when the first began, and whether it
traversed *crawling* (at least ``CRAWLED_M`` before the first; else it fell off a crest)
(:func:`app.core.experiment.body_upsets`), and how far the tail point advanced and how long the body lay along the
path at the end (:func:`app.core.experiment.end_pose`); :func:`with_upsets` computes those again for an older
summary. Then
``valid`` (1, or 0 for a run whose physics stopped being physics, ``invalid_reason`` saying what and when: its
measured columns are left empty, never data) and the outcome judged once the body is at rest after the motion
(:func:`app.core.experiment.judge_at_rest`): ``outcome`` (traversed, not traversed, undecided, invalid),
``at_rest_s``, ``rest_margin_m`` (how far the rearmost body point rests past the last far edge), ``advance_at_rest_m``,
``slide_back_m``. Every statistic (:func:`summary_table`, :func:`compare`, the figure) leaves invalid runs out and
counts them apart; the at-rest traversal rate leaves undecided runs out and counts them apart. Tail loads beyond what
friction can hold on a scene (``Scene.refuse_unholdable_load``, at every seed's friction) are refused before any
run. The
analysis reads only the recordings' results, so any run can be re-analysed later. The figure (``summary.svg``):
success rate, crawled rate and median advance against tail load, one line per scene × controller.

Controllers: ``feedforward``, ``feedback`` and the law's variants (:mod:`models.controllers`); every controller but
feedforward runs once per gain set. A sweep is checked whole before its first run — scenes, mode, seeds (whole
numbers ≥ 0), gain sets (at least one), tail loads, and the run count (at most
:data:`app.core.engines.MAX_RUNS`) — and stated (``N runs``) when it starts.

Where the runs go (:mod:`app.core.engines`): local processes (default, ``jobs`` at most the cores and the runs) or a
Dask cluster; each run a task writing its recording into the folder and returning its row. The folder is locked
while a sweep writes into it (a second one is refused). Each finished run is journaled (``finished.jsonl``) as it
finishes: Ctrl-C, SIGTERM or SIGHUP cancel what is pending, stop the workers and write ``summary.csv`` of the
finished runs; after that, or after a kill, the same command resumes (finished runs kept, the others run again). A
run that raised is a row whose ``file`` says ``failed: …`` and a row of ``failures.csv`` with its traceback; it runs
again on resume. ``sweep.json`` holds what the folder's sweep is (its runs' hash): another sweep into it is refused.

Qt-free; the caller's thread waits.
"""

from __future__ import annotations

import csv
import hashlib
import itertools
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from app.core.engines import (
    MAX_RUNS,
    Engine,
    FolderLock,
    Row,
    RunJournal,
    Task,
    capped_jobs,
    capped_words,
    check_scheduler,
    interruptible,
    open_engine,
)
from app.core.errors import InvalidRunError, RunsInterrupted, SweepError
from app.core.outputs import replace_text, replacing_text
from devices.config import LabConfig
from devices.toml_files import read_text_file, read_toml_file
from models.controllers import CONTROLLERS, uses_law
from models.errors import GainsError
from models.force_feedback import FeedbackGains

SWEEP_KEYS = {"scenes", "controllers", "tail_loads_n", "seeds", "seconds", "speed_rad_s", "settle_s", "mode", "gains",
              "repeat", "rest_cap_s", "ideal_sensing"}
SUMMARY_COLUMNS = ("run", "scene", "controller", "gains_index", "gains", "tail_load_N", "seed", "traversed",
                   "traverse_s", "advance_m", "overloads", "peak_current_mA", "front_face_cv", "wall_s", "file",
                   "lost_ground_s", "rolled_s", "crawl_m", "crawled", "tail_advance_m", "end_extent_m",
                   "valid", "invalid_reason", "outcome", "at_rest_s", "rest_margin_m", "advance_at_rest_m",
                   "slide_back_m")
FAILURE_COLUMNS = ("run", "scene", "controller", "gains_index", "tail_load_N", "seed", "error")
# What an invalid run leaves empty: everything it measured (its physics stopped being physics).
MEASURED_COLUMNS = ("traversed", "traverse_s", "advance_m", "front_face_cv", "lost_ground_s", "rolled_s", "crawl_m",
                    "crawled", "tail_advance_m", "end_extent_m", "at_rest_s", "rest_margin_m", "advance_at_rest_m",
                    "slide_back_m")


@dataclass(frozen=True)
class SweepPlan:
    scenes: tuple[str, ...]
    controllers: tuple[str, ...] = ("feedforward", "feedback")
    tail_loads_n: tuple[float, ...] = (0.0,)
    seeds: tuple[int, ...] = (0,)
    seconds: float = 60.0
    speed_rad_s: float = 0.1
    settle_s: float = 6.0
    mode: str = "follow"
    repeat: int = 1
    gains: tuple[FeedbackGains, ...] = field(default_factory=lambda: (FeedbackGains(),))
    rest_cap_s: float | None = None  # None: the experiment's default (app.core.experiment.REST_CAP_S)
    ideal_sensing: bool = False  # the controller's forces through the true calibration ([lab] sensing "ideal")

    def count(self) -> int:
        """How many runs :meth:`runs` gives, without building them (a sweep file can ask for 10⁸)."""
        per_cell = sum(len(self.gains) if uses_law(c) else 1 for c in self.controllers)
        return len(self.scenes) * per_cell * len(self.tail_loads_n) * len(self.seeds)

    def runs(self) -> list[dict[str, Any]]:
        """One dict of arguments per run (feedforward runs once per load and seed, not once per gain set)."""
        out = []
        for scene, controller, load, seed in itertools.product(self.scenes, self.controllers, self.tail_loads_n,
                                                               self.seeds):
            gain_sets = list(enumerate(self.gains)) if uses_law(controller) else [(-1, None)]
            for index, gains in gain_sets:
                out.append({"scene": scene, "controller": controller, "gains_index": index, "gains": gains,
                            "tail_load_n": float(load), "seed": int(seed)})
        return out


def read_sweep(path: str | Path) -> SweepPlan:
    path = Path(path)
    # Only a regular file of at most 1 MB, numbers a float can hold (devices.toml_files): one line naming the file.
    _text, data = read_toml_file(path, "sweep file", SweepError)
    for key in data:
        if key not in SWEEP_KEYS:
            raise SweepError(f"{path}: unknown key '{key}' (known: {', '.join(sorted(SWEEP_KEYS))})")
    if "scenes" not in data or not isinstance(data["scenes"], list) or not data["scenes"]:
        raise SweepError(f"{path}: 'scenes' must be a non-empty list of scene files or names")

    def numbers(key: str, default: tuple, kind: type) -> tuple:
        value = data.get(key, list(default))
        if not isinstance(value, list) or not value or not all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in value):
            raise SweepError(f"{path}: '{key}' must be a non-empty list of numbers")
        if kind is int and not all(isinstance(v, int) for v in value):  # seeds = [1.5] is no seed, not seed 1
            raise SweepError(f"{path}: '{key}' must be whole numbers, got {value!r}")
        return tuple(kind(v) for v in value)

    controllers = data.get("controllers", ["feedforward", "feedback"])
    if not isinstance(controllers, list) or not controllers or any(c not in CONTROLLERS for c in controllers) \
            or len(set(controllers)) != len(controllers):
        raise SweepError(f"{path}: 'controllers' must list some of {', '.join(CONTROLLERS)} (each once), got "
                         f"{controllers!r}")
    from app.core.experiment import MODES  # here, not at import: the experiment module loads MuJoCo

    mode = data.get("mode", "follow")
    if mode not in MODES:
        raise SweepError(f"{path}: 'mode' must be one of {', '.join(MODES)}, got {mode!r}")
    gains_tables = data.get("gains", [{}])
    if not isinstance(gains_tables, list) or not all(isinstance(g, dict) for g in gains_tables):
        raise SweepError(f"{path}: gain sets are written [[gains]] (an array of tables)")
    if not gains_tables:
        raise SweepError(f"{path}: 'gains' is empty: give at least one [[gains]] table (an empty one is the law's "
                         "defaults)")
    try:
        gains = tuple(FeedbackGains.from_mapping(g, f"{path} [[gains]] #{k + 1}") for k, g in enumerate(gains_tables))
    except GainsError as exc:
        raise SweepError(str(exc)) from None
    scalars: dict[str, Any] = {}  # SweepPlan's numbers (its other fields are not all floats)
    for key, default, positive in (("seconds", 60.0, True), ("speed_rad_s", 0.1, True), ("settle_s", 6.0, False),
                                   ("rest_cap_s", None, False)):
        if default is None and key not in data:
            continue
        value = data.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0 \
                or (positive and value == 0):
            raise SweepError(f"{path}: '{key}' must be a number {'>' if positive else '≥'} 0, got {value!r}")
        scalars[key] = float(value)
    from app.core.experiment import MAX_TAIL_LOAD_N

    tail_loads = numbers("tail_loads_n", (0.0,), float)
    if any(not 0.0 <= load <= MAX_TAIL_LOAD_N for load in tail_loads):
        # refused before any run: a negative load would be a forward push, every run would fail on its own
        raise SweepError(f"{path}: 'tail_loads_n' must be in [0, {MAX_TAIL_LOAD_N:g}] N, got {list(tail_loads)}")
    seeds = numbers("seeds", (0,), int)
    if any(s < 0 for s in seeds):
        raise SweepError(f"{path}: 'seeds' must be 0 or more")
    count = SweepPlan(scenes=tuple(str(s) for s in data["scenes"]), controllers=tuple(controllers),
                      tail_loads_n=tail_loads, seeds=seeds, gains=gains).count()
    if count > MAX_RUNS:
        raise SweepError(f"{path}: {count} runs (scenes × controllers × gain sets × tail loads × seeds); a sweep holds "
                         f"at most {MAX_RUNS}: split it")
    _refuse_unholdable_loads(path, [str(s) for s in data["scenes"]], max(tail_loads), seeds)
    repeat = data.get("repeat", 1)
    if isinstance(repeat, bool) or not isinstance(repeat, int) or not 1 <= repeat <= 100:
        raise SweepError(f"{path}: 'repeat' must be a whole number 1 … 100, got {repeat!r}")
    plan = SweepPlan(scenes=tuple(str(s) for s in data["scenes"]), controllers=tuple(controllers), repeat=repeat,
                     tail_loads_n=tail_loads, seeds=seeds, mode=str(mode), gains=gains, **scalars)
    ideal = data.get("ideal_sensing", False)
    if not isinstance(ideal, bool):
        raise SweepError(f"{path}: 'ideal_sensing' must be true or false, got {ideal!r}")
    return replace(plan, ideal_sensing=ideal)


def _refuse_unholdable_loads(path: Path, scenes: list[str], load_n: float, seeds: tuple[int, ...]) -> None:
    """A tail load no scene × seed of the sweep can hold (friction: ``Scene.refuse_unholdable_load``, on the
    friction each seed gives the scene) is refused before any run, naming the file, the scene and the formula."""
    from app.core.experiment import jittered_scene
    from devices.errors import SceneError
    from devices.scene import load_scene

    for name in scenes:
        try:
            base = load_scene(name)
        except SceneError as exc:
            raise SweepError(f"{path}: 'scenes': {exc}") from None
        for seed in seeds:
            scene = jittered_scene(base, seed) if seed > 0 else base
            try:
                scene.refuse_unholdable_load(load_n, "'tail_loads_n'" + (f" (seed {seed})" if seed > 0 else ""))
            except SceneError as exc:
                raise SweepError(f"{path}: {exc}") from None


def _lab_config(args: dict[str, Any]) -> LabConfig:
    """The lab config of a run: the default one, sensing ideally when the sweep says so (``ideal_sensing``)."""
    config = LabConfig()
    return replace(config, lab=replace(config.lab, sensing="ideal")) if args.get("ideal_sensing") else config


def _one(args: dict[str, Any]) -> dict[str, Any]:
    """One run (in a worker process): the recording written, its summary row returned."""
    from app.core.experiment import REST_CAP_S, run_experiment

    started = time.perf_counter()
    Path(args["out"]).unlink(missing_ok=True)  # a run cut short before (a kill, Ctrl-C) left its recording behind
    row = {"run": args["run"], "scene": args["scene"], "controller": args["controller"],
           "gains_index": args["gains_index"],
           "gains": json.dumps(asdict(args["gains"])) if args["gains"] is not None else "",
           "tail_load_N": args["tail_load_n"], "seed": args["seed"]}
    rest_cap_s = args.get("rest_cap_s")
    try:
        result = run_experiment(args["out"], _lab_config(args), scene=args.get("scene_path", args["scene"]), mode=args["mode"], seconds=args["seconds"],
                                speed_rad_s=args["speed_rad_s"], settle_s=args["settle_s"], seed=args["seed"],
                                controller=args["controller"], gains=args["gains"], tail_load_n=args["tail_load_n"],
                                repeat=args.get("repeat", 1), rest_cap_s=REST_CAP_S if rest_cap_s is None
                                else rest_cap_s, shape_scale=args.get("shape_scale", 1.0),
                                md={"plan_name": args["plan_name"]} if args.get("plan_name") else None)
    except InvalidRunError as exc:  # invalid before the capture: no recording
        return {**dict.fromkeys(SUMMARY_COLUMNS, ""), **row, "overloads": "", "wall_s": time.perf_counter() - started,
                "file": "", "valid": 0, "invalid_reason": str(exc), "outcome": "invalid"}
    row.update({"traversed": int(result.traversed),
                "traverse_s": result.traverse_s, "advance_m": result.advance_m, "overloads": len(result.overloads),
                "peak_current_mA": result.peak_current_ma, "front_face_cv": result.front_face_cv,
                "wall_s": time.perf_counter() - started, "file": Path(args["out"]).name,
                "lost_ground_s": result.lost_ground_s, "rolled_s": result.rolled_s, "crawl_m": result.crawl_m,
                "crawled": int(result.crawled_traverse), "tail_advance_m": result.tail_advance_m,
                "end_extent_m": result.end_extent_m, "valid": int(result.valid),
                "invalid_reason": result.invalid_reason, "outcome": result.outcome, "at_rest_s": result.at_rest_s,
                "rest_margin_m": result.rest_margin_m, "advance_at_rest_m": result.advance_at_rest_m,
                "slide_back_m": result.slide_back_m})
    if not result.valid:
        row.update(dict.fromkeys(MEASURED_COLUMNS, ""))
    return row


def sweep_tasks(plan: SweepPlan, out: Path) -> list[Task]:
    """The tasks of ``plan``'s runs, each with its recording's path in ``out``."""
    tasks = []
    for k, run in enumerate(plan.runs()):
        name = f"{k:03d}_{Path(run['scene']).stem}_{run['controller']}"
        name += f"_g{run['gains_index']}" if run["gains_index"] >= 0 else ""
        name += f"_load{run['tail_load_n']:g}_seed{run['seed']}.h5"
        tasks.append({**run, "run": k, "out": str(out.resolve() / name), "scene_path": scene_path(run["scene"]),
                      "mode": plan.mode, "seconds": plan.seconds,
                      "speed_rad_s": plan.speed_rad_s, "settle_s": plan.settle_s, "repeat": plan.repeat,
                      "rest_cap_s": plan.rest_cap_s,
                      # only when set: a sweep folder of before the key resumes as the same tasks
                      **({"ideal_sensing": True} if plan.ideal_sensing else {})})
    return tasks


def scene_path(scene: str) -> str:
    """A scene's file as an absolute path (a worker of another engine may run in another folder)."""
    from devices.scene import resolve_scene_path

    return str(resolve_scene_path(scene).resolve())


def tasks_identity(tasks: list[Task]) -> str:
    """SHA-256 of what the tasks run (every argument but where the recording is written, beyond its name)."""
    plain = [{k: (asdict(v) if isinstance(v, FeedbackGains) else Path(v).name if k == "out" else v)
              for k, v in sorted(task.items())} for task in tasks]
    return hashlib.sha256(json.dumps(plain, sort_keys=True, default=str).encode("utf-8")).hexdigest()


def claim_folder(out: Path, kind: str, identity: str, runs: int, refuse: type[ValueError] = SweepError,
                 extra: dict[str, Any] | None = None) -> bool:
    """Make ``out`` this ``kind``'s folder (``<kind>.json``: its identity and run count), or check that it is: one
    of another identity is refused, one whose every run finished and was summarised is refused as done. Returns
    True when it resumes an earlier start. The caller holds the folder's lock."""
    state = out / f"{kind}.json"
    if not state.exists():
        if (out / "summary.csv").exists():
            raise refuse(f"{out}: holds a sweep already (summary.csv); choose another --out folder")
        replace_text(state, json.dumps({"kind": kind, "identity": identity, "runs": runs, **(extra or {})}, indent=1))
        return False
    try:
        held = json.loads(read_text_file(state, f"{kind} folder's record", refuse))  # a planted FIFO: named
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise refuse(f"{state}: not a {kind} folder's record; choose another --out folder") from None
    if held.get("identity") != identity:
        raise refuse(f"{out}: holds another {kind} (its runs differ from these: another file or options); choose "
                     "another --out folder")
    if (out / "summary.csv").exists() and len(RunJournal(out).load()) >= runs:
        raise refuse(f"{out}: holds a {kind} already, finished (all {runs} runs, summary.csv); choose another --out "
                     "folder")
    return True


def execute(tasks: list[Task], engine: Engine, journal: RunJournal | None,
            progress: Callable[[str], None] | None = None) -> tuple[dict[int, Row], dict[int, str]]:
    """Run the tasks not yet in ``journal`` on ``engine``: (every row by run index, finished before or now, a failed
    run's row saying so; the traceback of each failed run by index). Each finished run is journaled as it finishes.
    :class:`RunsInterrupted` propagates (what finished is in the journal)."""
    done = journal.load() if journal is not None else {}
    rows: dict[int, Row] = {k: v for k, v in done.items() if k in {t["run"] for t in tasks}}
    todo = [task for task in tasks if task["run"] not in rows]
    failures: dict[int, str] = {}
    started = time.monotonic()
    total = len(tasks)

    def on_done(k: int, row: Row | None, error: str) -> None:
        task = todo[k]
        if row is None:
            failures[task["run"]] = error
            last = error.strip().splitlines()[-1] if error.strip() else "failed"
            row = {**dict.fromkeys(SUMMARY_COLUMNS, ""), "run": task["run"], "scene": task["scene"],
                   "controller": task["controller"], "gains_index": task["gains_index"],
                   "tail_load_N": task["tail_load_n"], "seed": task["seed"], "file": f"failed: {last}"}
        elif journal is not None:
            journal.add(row)
        rows[task["run"]] = row
        if progress is not None:
            now_done = len(rows)
            elapsed = time.monotonic() - started
            fresh = now_done - (total - len(todo))
            left = elapsed / max(fresh, 1) * (total - now_done)
            bar = "#" * int(30 * now_done / max(total, 1))
            progress(f"[{bar:<30}] {now_done}/{total} runs, {elapsed:.0f} s, about {left:.0f} s left")

    with interruptible():
        engine.run(_one, todo, on_done)
    return rows, failures


def run_sweep(plan: SweepPlan, out_dir: str | Path, *, jobs: int | None = None, engine: str = "local",
              scheduler: str | None = None, progress: Callable[[str], None] | None = None,
              say: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Run every run of ``plan`` into ``out_dir`` (created) on ``engine`` (:func:`app.core.engines.open_engine`;
    ``jobs`` at a time, at most the cores and the runs). A folder holding another sweep, or this one finished, is
    refused; one holding this sweep cut short resumes it. ``say`` gets the one-line statements (run count, engine,
    resuming). Returns the summary rows in run order; on :class:`RunsInterrupted` the summary of the finished runs
    is written before it propagates."""
    check_scheduler(scheduler if engine == "dask" else None)  # before anything is written
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tasks = sweep_tasks(plan, out)
    with FolderLock(out, "sweep"):
        resumed = claim_folder(out, "sweep", tasks_identity(tasks), len(tasks))
        journal = RunJournal(out)
        finished = len(journal.load())
        width = capped_jobs(jobs, len(tasks) - finished)
        runner = open_engine(engine, width, scheduler)
        if say is not None:
            say(f"{len(tasks)} runs" + (f", {finished} finished before (resuming)" if resumed else "") +
                f", on {runner.description}{capped_words(jobs, width)}")
        try:
            rows, failures = execute(tasks, runner, journal, progress)
        except RunsInterrupted as stop:
            done = journal.load()
            write_summary(out, [done[k] for k in sorted(done)], {})
            stop.finished, stop.total = len(done), len(tasks)
            raise
        finally:
            runner.close()
        ordered = [rows[k] for k in sorted(rows)]
        write_summary(out, ordered, failures, tasks)
    return ordered


def write_summary(out: Path, rows: list[Row], failures: dict[int, str], tasks: list[Task] | None = None) -> None:
    """``summary.csv`` (replaced whole, never half-written), ``failures.csv`` (one row per failed run, with its
    traceback; removed when none failed) and ``summary.svg`` of ``rows``."""
    with replacing_text(out / "summary.csv") as f:
        writer = csv.DictWriter(f, fieldnames=SUMMARY_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    by_run = {t["run"]: t for t in tasks or []}
    if failures:
        with replacing_text(out / "failures.csv") as f:
            writer = csv.DictWriter(f, fieldnames=FAILURE_COLUMNS)
            writer.writeheader()
            for k in sorted(failures):
                task = by_run.get(k, {})
                writer.writerow({"run": k, "scene": task.get("scene", ""), "controller": task.get("controller", ""),
                                 "gains_index": task.get("gains_index", ""),
                                 "tail_load_N": task.get("tail_load_n", ""), "seed": task.get("seed", ""),
                                 "error": failures[k]})
    else:
        (out / "failures.csv").unlink(missing_ok=True)
    replace_text(out / "summary.svg", summary_svg(rows))


def read_summary(path: str | Path) -> list[dict[str, Any]]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def with_upsets(rows: list[dict[str, Any]], folder: str | Path) -> list[dict[str, Any]]:
    """``rows`` (a summary, possibly from before the upset columns existed) with ``lost_ground_s``, ``rolled_s``,
    ``crawl_m``, ``crawled``, ``tail_advance_m`` and ``end_extent_m`` computed again from the recordings in ``folder``
    (the analysis reads only the recordings)."""
    from app.core.experiment import crawled, pose_from_recording, upsets_from_recording

    out = []
    for row in rows:
        row = dict(row)
        if row.get("traversed", "") != "":
            lost, rolled, crawl = upsets_from_recording(Path(folder) / str(row["file"]))
            tail, extent = pose_from_recording(Path(folder) / str(row["file"]))
            row.update(lost_ground_s=lost, rolled_s=rolled, crawl_m=crawl,
                       crawled=int(crawled(bool(int(row["traversed"])), crawl)), tail_advance_m=tail,
                       end_extent_m=extent)
        out.append(row)
    return out


def is_invalid(row: dict[str, Any]) -> bool:
    """A summary row of a run whose physics stopped being physics (``valid`` 0; a summary from before the column
    has none)."""
    return str(row.get("valid", "")).strip() in ("0", "0.0", "False")


def _groups(rows: list[dict[str, Any]]) -> dict[tuple[str, str], dict[float, list[dict[str, Any]]]]:
    """Rows by (scene, controller label) and tail load: the runs that finished (valid or not; a failed run, which
    has no result, is left out)."""
    groups: dict[tuple[str, str], dict[float, list[dict[str, Any]]]] = {}
    for row in rows:
        if row.get("traversed", "") == "" and not is_invalid(row):
            continue
        label = row["controller"] + (f" g{row['gains_index']}" if int(row["gains_index"]) >= 0 else "")
        key = (Path(str(row["scene"])).stem, label)
        groups.setdefault(key, {}).setdefault(float(row["tail_load_N"]), []).append(row)
    return groups


def summary_table(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per scene × controller (× gain set) × tail load, over the valid runs (``runs``): success rate, median advance
    (m), overload events, the rate of crawled traversals (NaN for a summary without that column), and the outcome at
    rest — ``at_rest_success`` the share traversed among the runs decided at rest (NaN: none, or a summary without the
    column), ``undecided`` how many were still moving at the cap; ``invalid`` counts the runs left out as no data."""
    table = []
    for (scene, label), by_load in sorted(_groups(rows).items()):
        for load, every in sorted(by_load.items()):
            group = [r for r in every if not is_invalid(r)]
            outcomes = [str(r.get("outcome", "")) for r in group]
            decided = [o for o in outcomes if o in ("traversed", "not traversed")]
            table.append({"scene": scene, "controller": label, "tail_load_N": load, "runs": len(group),
                          "success": float(np.mean([int(r["traversed"]) for r in group])) if group else math.nan,
                          "median_advance_m": float(np.median([float(r["advance_m"]) for r in group]))
                          if group else math.nan,
                          "overloads": int(sum(int(r["overloads"]) for r in group)),
                          "crawled": _crawled_rate(group),
                          "at_rest_success": float(np.mean([o == "traversed" for o in decided])) if decided
                          else math.nan,
                          "undecided": outcomes.count("undecided"),
                          "invalid": len(every) - len(group)})
    return table


@dataclass(frozen=True)
class Comparison:
    """Feedback against feedforward over paired runs (same scene, tail load and seed)."""

    candidate: str
    pairs: int
    ff_fail_cases: int  # scene × load cases where feedforward traversed in fewer than all of its runs
    ff_success_in_those: float
    fb_success_in_those: float
    ff_crawled_in_those: float  # … traversed crawling, not falling off a crest (NaN: not known)
    fb_crawled_in_those: float
    ff_crawl_in_those: float  # median crawl (m) of those runs: the advance before the body fell or rolled
    fb_crawl_in_those: float
    median_advance_ratio: float  # median over pairs of feedback's advance / feedforward's (positive advances)
    ff_overloads: int
    fb_overloads: int
    slower_where_ff_succeeds: float  # median of (feedback's time to traverse / feedforward's − 1), both traversed
    # Read beside the advance ratio (not one of the four yardsticks): the tail point's advance ratio over the same pairs,
    # and the centroid's over the pairs both traverse, where the tail ends alike and the centroid's ratio is mostly how
    # the body lay down (end_pose). NaN for a summary without the columns.
    median_tail_advance_ratio: float = math.nan
    median_advance_ratio_both_traversed: float = math.nan
    invalid_runs: int = 0  # runs of either controller left out as invalid (their pairs with them)


def _crawled_rate(rows: list[dict[str, Any]]) -> float:
    known = [int(r["crawled"]) for r in rows if str(r.get("crawled", "")) not in ("", "nan")]
    return float(np.mean(known)) if rows and len(known) == len(rows) else math.nan


def _median_of(rows: list[dict[str, Any]], key: str) -> float:
    known = [float(r[key]) for r in rows if str(r.get(key, "")) not in ("", "nan")]
    return float(np.median(known)) if rows and len(known) == len(rows) else math.nan


def compare(rows: list[dict[str, Any]], candidate_gains: int = 0, controller: str = "feedback") -> Comparison:
    """The yardsticks of ``controller`` (the law or a variant) with gain set ``candidate_gains`` against
    feedforward."""
    done = [r for r in rows if r.get("traversed", "") != "" and not is_invalid(r)]
    invalid = sum(1 for r in rows if is_invalid(r) and (r["controller"] == "feedforward" or (
        r["controller"] == controller and int(r["gains_index"]) == candidate_gains)))
    ff = {(Path(str(r["scene"])).stem, float(r["tail_load_N"]), int(r["seed"])): r for r in done
          if r["controller"] == "feedforward"}
    fb = {(Path(str(r["scene"])).stem, float(r["tail_load_N"]), int(r["seed"])): r for r in done
          if r["controller"] == controller and int(r["gains_index"]) == candidate_gains}
    keys = sorted(set(ff) & set(fb))
    cases: dict[tuple[str, float], list[tuple[str, float, int]]] = {}
    for key in keys:
        cases.setdefault(key[:2], []).append(key)
    failing = [c for c, ks in cases.items() if np.mean([int(ff[k]["traversed"]) for k in ks]) < 1.0]
    in_failing = [k for c in failing for k in cases[c]]
    ratios = [float(fb[k]["advance_m"]) / float(ff[k]["advance_m"]) for k in keys if float(ff[k]["advance_m"]) > 0.01]
    both = [k for k in keys if int(ff[k]["traversed"]) and int(fb[k]["traversed"])]
    slower = [float(fb[k]["traverse_s"]) / float(ff[k]["traverse_s"]) - 1 for k in both]
    ratioed = [k for k in keys if float(ff[k]["advance_m"]) > 0.01]
    tails = [(_number(ff[k], "tail_advance_m"), _number(fb[k], "tail_advance_m")) for k in ratioed]
    tail_ratios = [b / a for a, b in tails if a > 0.01] if all(math.isfinite(a) for a, _ in tails) else []
    both_ratios = [float(fb[k]["advance_m"]) / float(ff[k]["advance_m"]) for k in both if k in ratioed]
    return Comparison(
        candidate=f"{controller} g{candidate_gains}", pairs=len(keys), ff_fail_cases=len(failing),
        ff_success_in_those=float(np.mean([int(ff[k]["traversed"]) for k in in_failing])) if in_failing else math.nan,
        fb_success_in_those=float(np.mean([int(fb[k]["traversed"]) for k in in_failing])) if in_failing else math.nan,
        ff_crawled_in_those=_crawled_rate([ff[k] for k in in_failing]),
        fb_crawled_in_those=_crawled_rate([fb[k] for k in in_failing]),
        ff_crawl_in_those=_median_of([ff[k] for k in in_failing], "crawl_m"),
        fb_crawl_in_those=_median_of([fb[k] for k in in_failing], "crawl_m"),
        median_advance_ratio=float(np.median(ratios)) if ratios else math.nan,
        ff_overloads=int(sum(int(ff[k]["overloads"]) for k in keys)),
        fb_overloads=int(sum(int(fb[k]["overloads"]) for k in keys)),
        slower_where_ff_succeeds=float(np.median(slower)) if slower else math.nan,
        median_tail_advance_ratio=float(np.median(tail_ratios)) if tail_ratios else math.nan,
        median_advance_ratio_both_traversed=float(np.median(both_ratios)) if both_ratios else math.nan,
        invalid_runs=invalid)


def _number(row: dict[str, Any], key: str) -> float:
    """``row[key]`` as a float; NaN when the column is missing or empty (a summary from before it existed)."""
    text = str(row.get(key, ""))
    return float(text) if text not in ("", "nan") else math.nan


_DASHES = ("7 4", "2 3", "9 3 2 3", "12 4", "4 2 4 6")


def _dash(label: str) -> str:
    """The stroke pattern of a series: solid for feedforward, one pattern per feedback gain set ('feedback g1')."""
    if label.startswith("feedforward"):
        return ""
    index = int(label.rsplit("g", 1)[1]) if " g" in label else 0
    return f' stroke-dasharray="{_DASHES[index % len(_DASHES)]}"'


def summary_svg(rows: list[dict[str, Any]], width: int | None = None, height: int = 380) -> str:
    """Panels against tail load — success rate, the rate of crawled traversals (when the summary has it: not a fall
    off a crest), median advance — one colour per scene, solid for feedforward, dashed for feedback (a dash pattern per
    gain set: g0 dashed, g1 dotted, g2 dash-dot, …); the legend on the right. In the rate panels the series are drawn a few pixels apart (at most ±6 px),
    so that equal rates stay visible."""
    table = [e for e in summary_table(rows) if e["runs"]]  # a load whose every run was invalid has no point
    series: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for entry in table:
        series.setdefault((entry["scene"], entry["controller"]), []).append(entry)
    loads = sorted({e["tail_load_N"] for e in table}) or [0.0]
    x_lo, x_hi = loads[0], max(loads[-1], loads[0] + 1e-9)
    adv_max = max([e["median_advance_m"] for e in table] + [0.1])
    adv_min = min([e["median_advance_m"] for e in table] + [0.0])
    colours = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f"]
    scenes = sorted({scene for scene, _ in series})
    panels: list[tuple[str, str, float, float]] = [("traversed (fraction of runs)", "success", 0.0, 1.0)]
    if table and all(math.isfinite(e["crawled"]) for e in table):
        panels.append(("traversed crawling (not falling off a crest)", "crawled", 0.0, 1.0))
    panels.append(("median advance of the centroid (m)", "median_advance_m", adv_min, adv_max))
    panel_w, top, bottom, left, gap = 330.0, 40, height - 50, 60, 70
    legend_x = left + len(panels) * panel_w + (len(panels) - 1) * gap + 30
    width = width or int(legend_x + 330)
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" '
             f'font-size="12"><rect width="100%" height="100%" fill="white"/>']
    for panel, (title, key, lo, hi) in enumerate(panels):
        x0 = left + panel * (panel_w + gap)
        parts.append(f'<text x="{x0 + panel_w / 2}" y="20" text-anchor="middle">{title}</text>')
        parts.append(f'<line x1="{x0}" y1="{bottom}" x2="{x0 + panel_w}" y2="{bottom}" stroke="black"/>')
        parts.append(f'<line x1="{x0}" y1="{top}" x2="{x0}" y2="{bottom}" stroke="black"/>')

        def x_of(load: float, x0: float = x0) -> float:
            return x0 + 10 + (panel_w - 20) * (load - x_lo) / (x_hi - x_lo)

        for tick in loads:
            parts.append(f'<text x="{x_of(tick):.1f}" y="{bottom + 15}" text-anchor="middle">{tick:g}</text>')
        parts.append(f'<text x="{x0 + panel_w / 2}" y="{bottom + 32}" text-anchor="middle">tail load (N)</text>')
        for frac in (0.0, 0.25, 0.5, 0.75, 1.0):
            value = lo + frac * (hi - lo)
            y = bottom - frac * (bottom - top)
            parts.append(f'<text x="{x0 - 6}" y="{y + 4}" text-anchor="end">{value:.2f}</text>')
            parts.append(f'<line x1="{x0}" y1="{y}" x2="{x0 + panel_w}" y2="{y}" stroke="#dddddd"/>')
        for k, ((scene, label), entries) in enumerate(sorted(series.items())):
            colour = colours[scenes.index(scene) % len(colours)]
            dash = _dash(label)
            # success rates coincide often (all 0 or all 1): each series is drawn up to ±6 px apart so none hides
            nudge = ((k - (len(series) - 1) / 2) * min(12.0 / max(len(series) - 1, 1), 3.0)
                     if key in ("success", "crawled") else 0.0)
            points = " ".join(f"{x_of(e['tail_load_N']):.1f},"
                              f"{bottom - (e[key] - lo) / max(hi - lo, 1e-9) * (bottom - top) + nudge:.1f}"
                              for e in entries)
            parts.append(f'<polyline points="{points}" fill="none" stroke="{colour}" stroke-width="2"{dash}/>')
    for k, (scene, label) in enumerate(sorted(series)):
        colour = colours[scenes.index(scene) % len(colours)]
        dash = _dash(label)
        y = top + 16 * k
        parts.append(f'<line x1="{legend_x}" y1="{y - 4}" x2="{legend_x + 26}" y2="{y - 4}" stroke="{colour}" '
                     f'stroke-width="2"{dash}/>')
        parts.append(f'<text x="{legend_x + 32}" y="{y}" fill="{colour}">{scene}: {label}</text>')
    parts.append("</svg>")
    return "\n".join(parts)
