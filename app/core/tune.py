"""Tuning the force-feedback law's gains with Optuna (``sensnake experiment tune TUNE.toml --trials N --out DIR``).

A tuning file (TOML; unknown keys refused, naming the key)::

    train_scenes = ["paper_obstacle", "benchmarks/scenes/low_cylinder.toml"]   # what the optimiser sees
    test_scenes = ["benchmarks/scenes/tall_cylinder.toml"]   # never seen by it; scored once, for the best gains
    tail_loads_n = [0.0, 1.0]
    seeds = [1, 2]                 # run seeds (whole numbers ≥ 0)
    seconds = 40.0                 # the play's time limit
    speed_rad_s = 0.1
    settle_s = 6.0
    rest_cap_s = 30.0
    repeat = 1
    controller = "feedback"        # or a variant of the law (models.controllers)
    sampler = "tpe"                # or "cmaes"
    sampler_seed = 0
    start_from_defaults = true     # the law's defaults are the first trial (their training score, for comparison)
    keep_recordings = "best"       # "best": only the best trial's recordings are kept; "all"
    [objective]
    overload_penalty_m = 0.05      # metres of advance one more overload event than feedforward costs
    slide_back_weight = 1.0        # per metre of slide-back beyond feedforward's
    min_decided = 0.5              # a trial decided at rest on fewer of its conditions than this share fails
    [space]                        # each searched gain: [low, high] or [low, high, "log"]; the rest stay the base's
    push_gain = [0.0, 0.5]
    target_n = [3.0, 15.0, "log"]
    [base]                         # optional: the gains not searched (default: the law's defaults)

A *condition* is (scene, tail load, seed); the training conditions are ``train_scenes × tail_loads_n × seeds``, the
test conditions the same with ``test_scenes``. A test scene that is also a training scene (the same file, or the
same text) is refused. The objective of a trial (maximised): over the training conditions where both its run and
feedforward's are valid and decided at rest,

    score_c = (A_c − A_c^ff) − overload_penalty_m · max(0, O_c − O_c^ff) − slide_back_weight · max(0, S_c − S_c^ff)

with A the centroid's advance at rest (m), O the overload events, S the slide-back at rest (m); the trial's value is
the median of score_c. Invalid or undecided conditions are left out and counted; a trial with fewer than
``min_decided`` of its conditions left fails (no value). Feedforward's runs are made once and kept in
``DIR/baselines`` (a journal per split). A trial runs its gain set on the training conditions in batches of the
engine's width, reporting the running value after each batch to Optuna's median pruner (a trial behind the median of
earlier trials at the same step is pruned).

The study is Optuna's JournalStorage in ``DIR/study.journal`` (a file; ``optuna-dashboard DIR/study.journal`` opens
it): the same command with a larger ``--trials`` adds trials to it, never restarts it; a trial cut short by a kill is
marked failed on resume and its parameters tried again. Written after every trial: ``trials.csv``; at the end:
``best_gains.toml`` (a gains file ``experiment run --gains`` takes), ``report.csv`` (the best gains' and the
defaults' train and test scores against feedforward) and ``tune.svg`` (the history and the best trial's advance per
condition). The folder records the file's SHA-256 (``tune.json``): a folder of another file is refused.

Qt-free; called from the command's main thread.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from app.core.engines import (
    Engine,
    FolderLock,
    RunJournal,
    Task,
    capped_jobs,
    capped_words,
    check_scheduler,
    cores,
    open_engine,
    read_folder_record,
)
from app.core.errors import RunsInterrupted, TuneError
from app.core.outputs import replace_text, replacing_text
from app.core.sweep import _refuse_unholdable_loads, execute, is_invalid, scene_path
from devices.toml_files import read_toml_file
from models.controllers import CONTROLLERS, FEEDFORWARD
from models.errors import GainsError
from models.force_feedback import GAIN_RANGES, FeedbackGains

TUNE_KEYS = {"train_scenes", "test_scenes", "tail_loads_n", "seeds", "seconds", "speed_rad_s", "settle_s",
             "rest_cap_s", "repeat", "controller", "sampler", "sampler_seed", "start_from_defaults",
             "keep_recordings", "objective", "space", "base", "note"}
OBJECTIVE_KEYS = {"overload_penalty_m", "slide_back_weight", "min_decided"}
SAMPLERS = ("tpe", "cmaes")
MAX_TRIALS = 10_000
MAX_CONDITIONS = 1_000  # training conditions a trial (a trial of 1,000 one-minute runs is ~8 hours on 2 cores)
TRIAL_COLUMNS_HEAD = ("trial", "state", "value", "conditions", "decided", "median_advance_delta_m",
                      "overload_delta", "duration_s", "note")
# What a trial keeps of each of its runs (in the study: a trial's recordings may be removed, keep_recordings)
KEPT_COLUMNS = ("valid", "invalid_reason", "outcome", "traversed", "advance_at_rest_m", "slide_back_m", "overloads")
REPORT_COLUMNS = ("gains", "trial", "split", "conditions", "decided", "objective", "median_advance_delta_m",
                  "feedforward_traversal", "candidate_traversal", "feedforward_overloads", "candidate_overloads",
                  "invalid", "undecided")


@dataclass(frozen=True)
class Objective:
    overload_penalty_m: float = 0.05
    slide_back_weight: float = 1.0
    min_decided: float = 0.5


@dataclass(frozen=True)
class SearchDimension:
    name: str
    low: float
    high: float
    log: bool = False


@dataclass(frozen=True)
class TunePlan:
    path: Path
    sha256: str
    train_scenes: tuple[str, ...]
    test_scenes: tuple[str, ...]
    space: tuple[SearchDimension, ...]
    tail_loads_n: tuple[float, ...] = (0.0,)
    seeds: tuple[int, ...] = (1,)
    seconds: float = 40.0
    speed_rad_s: float = 0.1
    settle_s: float = 6.0
    rest_cap_s: float = 30.0
    repeat: int = 1
    controller: str = "feedback"
    sampler: str = "tpe"
    sampler_seed: int = 0
    start_from_defaults: bool = True
    keep_recordings: str = "best"
    objective: Objective = Objective()
    base: FeedbackGains = FeedbackGains()

    def conditions(self, split: str) -> list[tuple[str, float, int]]:
        scenes = self.train_scenes if split == "train" else self.test_scenes
        return [(scene, load, seed) for scene in scenes for load in self.tail_loads_n for seed in self.seeds]


def _scene_identity(name: str) -> tuple[str, str]:
    from devices.scene import resolve_scene_path

    path = resolve_scene_path(name)
    text = path.read_text(encoding="utf-8") if path.is_file() else ""
    return str(path.resolve()), hashlib.sha256(text.encode("utf-8")).hexdigest()


def read_tune(path: str | Path) -> TunePlan:
    """Read and check a tuning file; :class:`TuneError` names the file and the key."""
    path = Path(path)
    text, data = read_toml_file(path, "tuning file", TuneError)
    for key in data:
        if key not in TUNE_KEYS:
            raise TuneError(f"{path}: unknown key '{key}' (known: {', '.join(sorted(TUNE_KEYS))})")

    def scenes(key: str) -> tuple[str, ...]:
        value = data.get(key)
        if not isinstance(value, list) or not value or not all(isinstance(v, str) and v for v in value):
            raise TuneError(f"{path}: '{key}' must be a non-empty list of scene files or names")
        return tuple(value)

    train, test = scenes("train_scenes"), scenes("test_scenes")
    try:  # the scenes must read (SPEC §6) before anything runs
        from devices.errors import SceneError
        from devices.scene import load_scene

        for name in (*train, *test):
            load_scene(name)
    except SceneError as exc:
        raise TuneError(f"{path}: {exc}") from None
    train_ids = {_scene_identity(s): s for s in train}
    for scene in test:
        where, digest = _scene_identity(scene)
        same = next((name for (w, d), name in train_ids.items() if w == where or d == digest), None)
        if same is not None:
            raise TuneError(f"{path}: test scene {scene!r} is also a training scene ({same!r}): the test set must be "
                            "scenes the optimiser never sees")

    def numbers(key: str, default: list[Any], whole: bool) -> tuple[Any, ...]:
        value = data.get(key, default)
        if not isinstance(value, list) or not value or not all(
                isinstance(v, int if whole else int | float) and not isinstance(v, bool) for v in value):
            raise TuneError(f"{path}: '{key}' must be a non-empty list of {'whole numbers' if whole else 'numbers'}, "
                            f"got {value!r}")
        return tuple(int(v) if whole else float(v) for v in value)

    from app.core.experiment import MAX_TAIL_LOAD_N

    loads = numbers("tail_loads_n", [0.0], False)
    if any(not 0.0 <= v <= MAX_TAIL_LOAD_N for v in loads):
        raise TuneError(f"{path}: 'tail_loads_n' must be in [0, {MAX_TAIL_LOAD_N:g}] N, got {list(loads)}")
    seeds = numbers("seeds", [1], True)
    if any(s < 0 for s in seeds):
        raise TuneError(f"{path}: 'seeds' must be 0 or more")
    per_trial = len(train) * len(loads) * len(seeds)
    if per_trial > MAX_CONDITIONS:  # each trial runs every training condition (and feedforward once each)
        raise TuneError(f"{path}: {per_trial} training conditions a trial (train scenes × tail loads × seeds); a "
                        f"tuning runs at most {MAX_CONDITIONS} a trial: draw fewer")
    scalars: dict[str, Any] = {}
    for key, default, low, high in (("seconds", 40.0, 0.5, 3600.0), ("speed_rad_s", 0.1, 0.001, 1.0),
                                    ("settle_s", 6.0, 0.0, 60.0), ("rest_cap_s", 30.0, 0.0, 600.0)):
        value = data.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
            raise TuneError(f"{path}: '{key}' must be a number in [{low:g}, {high:g}], got {value!r}")
        scalars[key] = float(value)
    for key, default, low, high in (("repeat", 1, 1, 100), ("sampler_seed", 0, 0, 2**31 - 1)):
        value = data.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise TuneError(f"{path}: '{key}' must be a whole number {low} … {high}, got {value!r}")
        scalars[key] = value
    controller = data.get("controller", "feedback")
    if controller not in CONTROLLERS or controller == FEEDFORWARD:
        raise TuneError(f"{path}: 'controller' must be one of "
                        f"{', '.join(c for c in CONTROLLERS if c != FEEDFORWARD)} (a law to tune), got {controller!r}")
    sampler = data.get("sampler", "tpe")
    if sampler not in SAMPLERS:
        raise TuneError(f"{path}: 'sampler' must be one of {', '.join(SAMPLERS)}, got {sampler!r}")
    keep = data.get("keep_recordings", "best")
    if keep not in ("best", "all"):
        raise TuneError(f"{path}: 'keep_recordings' must be \"best\" or \"all\", got {keep!r}")
    start = data.get("start_from_defaults", True)
    if not isinstance(start, bool):
        raise TuneError(f"{path}: 'start_from_defaults' must be true or false, got {start!r}")
    base_table = data.get("base", {})
    if not isinstance(base_table, dict):
        raise TuneError(f"{path}: [base] must be a table of the law's gains")
    try:
        base = FeedbackGains.from_mapping(base_table, f"{path} [base]")
    except GainsError as exc:
        raise TuneError(str(exc)) from None
    objective = _objective(path, data.get("objective", {}))
    space = _space(path, data.get("space"))
    plan = TunePlan(path=path, sha256=hashlib.sha256(text.encode("utf-8")).hexdigest(), train_scenes=train,
                    test_scenes=test, space=space, tail_loads_n=loads, seeds=seeds, controller=controller,
                    sampler=sampler, start_from_defaults=start, keep_recordings=keep, objective=objective, base=base,
                    **scalars)
    try:
        _refuse_unholdable_loads(path, [*train, *test], max(loads), seeds)
    except ValueError as exc:
        raise TuneError(str(exc)) from None
    return plan


def _objective(path: Path, table: Any) -> Objective:
    if not isinstance(table, dict):
        raise TuneError(f"{path}: [objective] must be a table")
    for key in table:
        if key not in OBJECTIVE_KEYS:
            raise TuneError(f"{path} [objective]: unknown key '{key}' (known: {', '.join(sorted(OBJECTIVE_KEYS))})")
    values = {}
    for f in fields(Objective):
        value = table.get(f.name, f.default)
        high = 1.0 if f.name == "min_decided" else 100.0
        if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= high:
            raise TuneError(f"{path} [objective]: '{f.name}' must be a number in [0, {high:g}], got {value!r}")
        values[f.name] = float(value)
    return Objective(**values)


def _space(path: Path, table: Any) -> tuple[SearchDimension, ...]:
    if not isinstance(table, dict) or not table:
        raise TuneError(f"{path}: [space] is empty: name at least one gain to search, as name = [low, high] or "
                        "[low, high, \"log\"]")
    dims = []
    for name, value in table.items():
        if name not in GAIN_RANGES:
            raise TuneError(f"{path} [space]: unknown gain '{name}' (known: {', '.join(sorted(GAIN_RANGES))})")
        log = isinstance(value, list) and len(value) == 3 and value[2] == "log"
        bounds = value[:2] if log else value
        if not (isinstance(bounds, list) and len(bounds) == 2 and all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in bounds)):
            raise TuneError(f"{path} [space]: '{name}' must be [low, high] or [low, high, \"log\"], got {value!r}")
        low, high = float(bounds[0]), float(bounds[1])
        safe_low, safe_high = GAIN_RANGES[name]
        if not (math.isfinite(low) and math.isfinite(high) and safe_low <= low < high <= safe_high):
            raise TuneError(f"{path} [space]: '{name}' = [{low:g}, {high:g}] must satisfy {safe_low:g} ≤ low < high "
                            f"≤ {safe_high:g} (its safe range)")
        if log and low <= 0:
            raise TuneError(f"{path} [space]: '{name}' on a log scale needs low > 0, got {low:g}")
        dims.append(SearchDimension(name, low, high, log))
    return tuple(dims)


# -- scoring ---------------------------------------------------------------------------------------------------------
def condition_key(scene: str, load: float, seed: int) -> str:
    return f"{Path(scene).stem}|{load:g}|{seed}"


def _number(row: dict[str, Any], key: str) -> float:
    text = str(row.get(key, ""))
    return float(text) if text not in ("", "nan") else math.nan


def condition_score(run: dict[str, Any], ff: dict[str, Any], objective: Objective) -> tuple[float, str]:
    """(score_c, "") of a run against feedforward's on its condition, or (NaN, why left out)."""
    if is_invalid(run) or is_invalid(ff):
        return math.nan, "invalid"
    if "undecided" in (run.get("outcome"), ff.get("outcome")) or str(run.get("traversed", "")) == "":
        return math.nan, "undecided"
    advance = _number(run, "advance_at_rest_m") - _number(ff, "advance_at_rest_m")
    overloads = max(0.0, _number(run, "overloads") - _number(ff, "overloads"))
    slide = max(0.0, _number(run, "slide_back_m") - _number(ff, "slide_back_m"))
    score = advance - objective.overload_penalty_m * overloads - objective.slide_back_weight * slide
    return (score, "") if math.isfinite(score) else (math.nan, "undecided")


@dataclass(frozen=True)
class Score:
    value: float  # NaN: too few conditions decided
    conditions: int
    decided: int
    invalid: int
    undecided: int
    median_advance_delta_m: float
    overload_delta: float
    ff_traversal: float
    candidate_traversal: float
    ff_overloads: float
    candidate_overloads: float


def score(runs: dict[str, dict[str, Any]], baselines: dict[str, dict[str, Any]], objective: Objective) -> Score:
    """The objective over the conditions of ``runs`` (by condition key) against ``baselines``."""
    scores, deltas, overload_deltas = [], [], []
    left = {"invalid": 0, "undecided": 0}
    ff_trav, cand_trav, ff_over, cand_over = [], [], [], []
    for key, run in runs.items():
        ff = baselines[key]
        value, why = condition_score(run, ff, objective)
        if why:
            left[why] += 1
            continue
        scores.append(value)
        deltas.append(_number(run, "advance_at_rest_m") - _number(ff, "advance_at_rest_m"))
        overload_deltas.append(_number(run, "overloads") - _number(ff, "overloads"))
        ff_trav.append(float(ff.get("outcome") == "traversed"))
        cand_trav.append(float(run.get("outcome") == "traversed"))
        ff_over.append(_number(ff, "overloads"))
        cand_over.append(_number(run, "overloads"))
    enough = len(scores) >= max(1, math.ceil(objective.min_decided * len(runs)))

    def mean(values: list[float]) -> float:
        return float(np.mean(values)) if values else math.nan

    return Score(float(np.median(scores)) if enough else math.nan, len(runs), len(scores), left["invalid"],
                 left["undecided"], float(np.median(deltas)) if deltas else math.nan, mean(overload_deltas),
                 mean(ff_trav), mean(cand_trav), mean(ff_over), mean(cand_over))


# -- the study -------------------------------------------------------------------------------------------------------
def _tasks(plan: TunePlan, split: str, controller: str, gains: FeedbackGains | None, folder: Path) -> list[Task]:
    tasks = []
    for k, (scene, load, seed) in enumerate(plan.conditions(split)):
        tasks.append({"run": k, "scene": scene, "scene_path": scene_path(scene), "controller": controller,
                      "gains_index": -1 if gains is None else 0, "gains": gains, "tail_load_n": load, "seed": seed,
                      "mode": "follow", "seconds": plan.seconds, "speed_rad_s": plan.speed_rad_s,
                      "settle_s": plan.settle_s, "repeat": plan.repeat, "rest_cap_s": plan.rest_cap_s,
                      "plan_name": "experiment tune", "key": condition_key(scene, load, seed),
                      "out": str((folder / f"{k:03d}_{Path(scene).stem}_load{load:g}_seed{seed}.h5").resolve())})
    return tasks


def _by_key(tasks: list[Task], rows: dict[int, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {task["key"]: rows[task["run"]] for task in tasks if task["run"] in rows}


def _run_split(plan: TunePlan, engine: Engine, split: str, controller: str, gains: FeedbackGains | None,
               folder: Path, progress: Callable[[str], None] | None) -> dict[str, dict[str, Any]]:
    """Every condition of ``split`` run once with ``controller`` into ``folder`` (journaled there: kept across
    commands); failed runs raise (a baseline or a test score needs every condition)."""
    folder.mkdir(parents=True, exist_ok=True)
    tasks = _tasks(plan, split, controller, gains, folder)
    rows, failures = execute(tasks, engine, RunJournal(folder), progress)
    if failures:
        first = next(iter(failures.values())).strip().splitlines()[-1]
        raise RuntimeError(f"{len(failures)} run(s) of {folder.name} failed ({first}); see {folder}")
    return _by_key(tasks, rows)


def gains_of(plan: TunePlan, params: dict[str, float]) -> FeedbackGains:
    """The base gains with the searched ones set (GainsError when the set is not a safe one)."""
    return FeedbackGains(**{**asdict(plan.base), **{k: float(v) for k, v in params.items()}})


def _gains_hash(gains: FeedbackGains) -> str:
    return hashlib.sha256(json.dumps(asdict(gains), sort_keys=True).encode("utf-8")).hexdigest()[:12]


def open_study(plan: TunePlan, out: Path) -> Any:
    """The study in ``out/study.journal`` (created or loaded), its sampler and pruner from the plan; trials left
    running by a command that was killed are marked failed and their parameters queued again."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend
    from optuna.trial import TrialState

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(str(out / "study.journal")))
    pruner = optuna.pruners.MedianPruner(n_startup_trials=3, n_warmup_steps=0)
    study = optuna.create_study(study_name="sensnake-tune", storage=storage, pruner=pruner, direction="maximize",
                                load_if_exists=True)
    # The sampler's seed moves on with the study: a resumed study seeded as at its start would draw its first
    # (random, startup) points again.
    seed = plan.sampler_seed + len(study.get_trials(deepcopy=False))
    if plan.sampler == "cmaes":
        study.sampler = optuna.samplers.CmaEsSampler(seed=seed, warn_independent_sampling=False)
    else:
        study.sampler = optuna.samplers.TPESampler(seed=seed)
    study_id = storage.get_study_id_from_name("sensnake-tune")
    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        trial_id = storage.get_trial_id_from_study_id_trial_number(study_id, trial.number)
        storage.set_trial_user_attr(trial_id, "note", "cut short (the command was killed); tried again")
        storage.set_trial_state_values(trial_id, TrialState.FAIL)
        study.enqueue_trial(trial.params, skip_if_exists=False)
    if plan.start_from_defaults and not study.trials:
        defaults = {d.name: getattr(plan.base, d.name) for d in plan.space}
        if all(d.low <= defaults[d.name] <= d.high for d in plan.space):
            study.enqueue_trial(defaults, user_attrs={"note": "the base gains (the law's defaults unless [base])"})
    return study


def counted_trials(study: Any) -> list[Any]:
    """The trials that count toward ``--trials``: every one but those cut short by a kill (tried again)."""
    from optuna.trial import TrialState

    ended = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
    return [t for t in study.get_trials(deepcopy=False, states=ended)
            if "cut short" not in str(t.user_attrs.get("note", ""))]


def run_tune(plan: TunePlan, out_dir: str | Path, trials: int, *, jobs: int | None = None, engine: str = "local",
             scheduler: str | None = None, progress: Callable[[str], None] | None = None,
             say: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Add trials to the study in ``out_dir`` until it holds ``trials``, then score the best gains (and the
    defaults) on the training and the test conditions. Returns the rows of ``report.csv``."""
    from optuna.trial import TrialState

    if not 1 <= trials <= MAX_TRIALS:
        raise TuneError(f"--trials must be 1 … {MAX_TRIALS}, got {trials}")
    check_scheduler(scheduler if engine == "dask" else None)  # before anything is written
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with FolderLock(out, "tune"):
        record = out / "tune.json"
        if record.exists():
            held = read_folder_record(record, "tuning folder's record", TuneError)
            if held.get("sha256") != plan.sha256:
                raise TuneError(f"{out}: holds the study of another tuning file (sha256 "
                                f"{str(held.get('sha256'))[:16]}…, this file's {plan.sha256[:16]}…); choose another "
                                "--out folder")
        elif [p for p in out.iterdir() if p.name != ".lock"]:
            raise TuneError(f"{out}: not empty and holds no study; choose a new --out folder")
        else:
            replace_text(record, json.dumps({"kind": "tune", "sha256": plan.sha256, "file": str(plan.path),
                                             "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}, indent=1))
            replace_text(out / "tune.file.toml", plan.path.read_text(encoding="utf-8"))
        study = open_study(plan, out)
        done_before = len(counted_trials(study))
        train = plan.conditions("train")
        width = capped_jobs(jobs, len(train))
        runner = open_engine(engine, width, scheduler)
        if say is not None:
            say(f"study {out / 'study.journal'}: {done_before} trial(s) before, {max(trials - done_before, 0)} to "
                f"add; {len(train)} training conditions a trial, {len(plan.conditions('test'))} test conditions; "
                f"{plan.sampler} sampler; on {runner.description}{capped_words(jobs, width)}")
        try:
            baselines = _run_split(plan, runner, "train", FEEDFORWARD, None, out / "baselines" / "train", progress)
            while len(counted_trials(study)) < trials:
                _one_trial(plan, study, runner, width if engine == "local" else min(width, cores()) or 1, baselines,
                           out, progress)
                write_trials(study, plan, out)
            complete = [t for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))]
            if not complete:
                raise TuneError(f"{out}: no trial completed (all pruned or failed: trials.csv says why); nothing to "
                                "report")
            best = study.best_trial
            best_gains = gains_of(plan, best.params)
            _keep_best_recordings(plan, study, out)
            replace_text(
                out / "best_gains.toml",
                f"# best trial {best.number} of the study in {out / 'study.journal'}: objective {best.value:.4f} m on "
                f"the training conditions ({plan.path.name}, sha256 {plan.sha256[:16]}…)\n"
                f"# controller {plan.controller}\n" + "[feedback]\n" +
                "".join(f"{k} = {v!r}\n" for k, v in asdict(best_gains).items()))
            report = _report(plan, study, runner, best_gains, baselines, out, progress)
        finally:
            runner.close()
        write_trials(study, plan, out)
        replace_text(out / "tune.svg", tune_svg(study, plan, baselines))
    return report


def _one_trial(plan: TunePlan, study: Any, engine: Engine, width: int, baselines: dict[str, dict[str, Any]],
               out: Path, progress: Callable[[str], None] | None) -> None:
    from optuna.trial import TrialState

    trial = study.ask()
    started = time.monotonic()
    params = {d.name: trial.suggest_float(d.name, d.low, d.high, log=d.log) for d in plan.space}
    try:
        gains = gains_of(plan, params)
    except GainsError as exc:
        trial.set_user_attr("note", f"not a safe gain set: {exc}")
        study.tell(trial, state=TrialState.FAIL)
        return
    folder = out / "trials" / f"{trial.number:04d}"
    folder.mkdir(parents=True, exist_ok=True)
    tasks = _tasks(plan, "train", plan.controller, gains, folder)
    rows: dict[int, dict[str, Any]] = {}
    try:
        for start in range(0, len(tasks), width):
            batch = tasks[start:start + width]
            got, failures = execute(batch, engine, None, None)
            if failures:
                last = next(iter(failures.values())).strip().splitlines()[-1]
                trial.set_user_attr("note", f"{len(failures)} run(s) failed: {last}")
                study.tell(trial, state=TrialState.FAIL)
                return
            rows.update(got)
            partial = score(_by_key(tasks, rows), baselines, plan.objective)
            if progress is not None:
                progress(f"trial {trial.number}: {len(rows)}/{len(tasks)} conditions, running value "
                         f"{partial.value:+.4f}")
            if math.isfinite(partial.value) and len(rows) < len(tasks):
                trial.report(partial.value, step=len(rows))
                if trial.should_prune():
                    _attrs(trial, partial, started)
                    trial.set_user_attr("note", f"pruned after {len(rows)} of {len(tasks)} conditions")
                    study.tell(trial, state=TrialState.PRUNED)
                    return
    except RunsInterrupted:
        trial.set_user_attr("note", "cut short (interrupted); tried again")
        study.tell(trial, state=TrialState.FAIL)
        study.enqueue_trial(params)
        raise
    final = score(_by_key(tasks, rows), baselines, plan.objective)
    _attrs(trial, final, started)
    trial.set_user_attr("per_condition", {key: {k: (None if isinstance(row.get(k), float) and not
                                                    math.isfinite(row[k]) else row.get(k)) for k in KEPT_COLUMNS}
                                          for key, row in _by_key(tasks, rows).items()})
    if not math.isfinite(final.value):
        trial.set_user_attr("note", f"decided at rest on {final.decided} of {final.conditions} conditions (fewer "
                                    f"than {plan.objective.min_decided:g} of them): no value")
        study.tell(trial, state=TrialState.FAIL)
        return
    study.tell(trial, final.value)


def _attrs(trial: Any, s: Score, started: float) -> None:
    for key in ("conditions", "decided", "invalid", "undecided", "median_advance_delta_m", "overload_delta"):
        value = getattr(s, key)
        trial.set_user_attr(key, value if not isinstance(value, float) or math.isfinite(value) else None)
    trial.set_user_attr("duration_s", round(time.monotonic() - started, 1))


def _keep_best_recordings(plan: TunePlan, study: Any, out: Path) -> None:
    if plan.keep_recordings == "all":
        return
    try:
        best = study.best_trial.number
    except ValueError:
        return
    for folder in (out / "trials").glob("*"):
        if folder.is_dir() and folder.name != f"{best:04d}":
            shutil.rmtree(folder, ignore_errors=True)


def write_trials(study: Any, plan: TunePlan, out: Path) -> None:
    """``trials.csv``: every trial of the study, its state, value, the searched gains and what it decided on."""
    names = [d.name for d in plan.space]
    with replacing_text(out / "trials.csv") as f:
        writer = csv.writer(f)
        writer.writerow([*TRIAL_COLUMNS_HEAD[:3], *names, *TRIAL_COLUMNS_HEAD[3:]])
        for t in study.get_trials(deepcopy=False):
            attrs = t.user_attrs
            writer.writerow([t.number, t.state.name.lower(), "" if t.value is None else t.value,
                             *[t.params.get(n, "") for n in names],
                             *[("" if attrs.get(k) is None else attrs.get(k)) for k in TRIAL_COLUMNS_HEAD[3:]]])


def _report(plan: TunePlan, study: Any, engine: Engine, best_gains: FeedbackGains,
            train_baselines: dict[str, dict[str, Any]], out: Path, progress: Callable[[str], None] | None
            ) -> list[dict[str, Any]]:
    """The best gains and the base gains, each on the training and the test conditions, against feedforward
    (``report.csv``). The test conditions are run here, once per gain set (kept in ``DIR/test``)."""
    test_baselines = _run_split(plan, engine, "test", FEEDFORWARD, None, out / "baselines" / "test", progress)
    best = study.best_trial
    sets = [("best", best.number, best_gains)]
    if _gains_hash(plan.base) != _gains_hash(best_gains):
        sets.append(("base", _trial_of(study, plan.base), plan.base))
    rows = []
    for label, number, gains in sets:
        for split, baselines in (("train", train_baselines), ("test", test_baselines)):
            if split == "train" and number is not None:  # what the study kept of that trial's runs
                runs = _rows_of_trial(study, number)
            else:
                runs = _run_split(plan, engine, split, plan.controller, gains,
                                  out / split / f"{label}-{_gains_hash(gains)}", progress)
            s = score(runs, baselines, plan.objective)
            rows.append({"gains": label, "trial": "" if number is None else number, "split": split,
                         "conditions": s.conditions, "decided": s.decided, "objective": s.value,
                         "median_advance_delta_m": s.median_advance_delta_m,
                         "feedforward_traversal": s.ff_traversal, "candidate_traversal": s.candidate_traversal,
                         "feedforward_overloads": s.ff_overloads, "candidate_overloads": s.candidate_overloads,
                         "invalid": s.invalid, "undecided": s.undecided})
    with replacing_text(out / "report.csv") as f:
        f.write(f"# tuning file {plan.path.name} sha256 {plan.sha256}; objective = median over decided conditions "
                f"of (advance − feedforward's) − {plan.objective.overload_penalty_m:g} m × extra overloads − "
                f"{plan.objective.slide_back_weight:g} × extra slide-back\n")
        writer = csv.DictWriter(f, fieldnames=REPORT_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return rows


def _trial_of(study: Any, gains: FeedbackGains) -> int | None:
    """The completed trial whose gains are ``gains`` (the enqueued defaults), if any."""
    from optuna.trial import TrialState

    for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)):
        if all(math.isclose(getattr(gains, k), v, rel_tol=1e-12, abs_tol=1e-15) for k, v in t.params.items()):
            return int(t.number)
    return None


def _rows_of_trial(study: Any, number: int) -> dict[str, dict[str, Any]]:
    """A finished trial's runs as the study kept them (its recordings may be gone: ``keep_recordings``)."""
    per = study.trials[number].user_attrs.get("per_condition", {})
    return {key: {k: ("nan" if v is None else v) for k, v in row.items()} for key, row in per.items()}


def read_report(path: str | Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


# -- the figure ------------------------------------------------------------------------------------------------------
def tune_svg(study: Any, plan: TunePlan, baselines: dict[str, dict[str, Any]]) -> str:
    """Left: each trial's value (dots; pruned and failed ones on the axis as crosses) and the best so far (line).
    Right: the best trial's advance at rest on each training condition beside feedforward's."""
    from optuna.trial import TrialState

    trials = study.get_trials(deepcopy=False)
    values = [t.value for t in trials if t.state == TrialState.COMPLETE and t.value is not None]
    lo, hi = (min(values + [0.0]), max(values + [0.0])) if values else (-1.0, 1.0)
    if hi - lo < 1e-9:
        lo, hi = lo - 0.1, hi + 0.1
    w, h, left, top = 380.0, 260.0, 60.0, 50.0
    bottom = top + h
    parts = ['<svg xmlns="http://www.w3.org/2000/svg" width="940" height="380" font-family="sans-serif" '
             'font-size="12"><rect width="100%" height="100%" fill="white"/>',
             f'<text x="{left}" y="20">{plan.path.name} (sha256 {plan.sha256[:16]}…): {plan.controller}, '
             f'{plan.sampler} sampler, {len(trials)} trials</text>',
             f'<text x="{left + w / 2}" y="{top - 8}" text-anchor="middle">objective (m) by trial; line: best so '
             f'far</text>',
             f'<rect x="{left}" y="{top}" width="{w}" height="{h}" fill="none" stroke="black"/>']
    n = max(len(trials), 1)

    def x_of(k: float) -> float:
        return left + 10 + (w - 20) * (k / max(n - 1, 1))

    def y_of(v: float) -> float:
        return bottom - (v - lo) / (hi - lo) * h

    for frac in (0.0, 0.5, 1.0):
        v = lo + frac * (hi - lo)
        parts.append(f'<text x="{left - 5}" y="{y_of(v) + 4:.1f}" text-anchor="end">{v:+.2f}</text>')
    best_line = []
    best = -math.inf
    for t in trials:
        if t.state == TrialState.COMPLETE and t.value is not None:
            parts.append(f'<circle cx="{x_of(t.number):.1f}" cy="{y_of(t.value):.1f}" r="3.5" fill="#1f77b4"/>')
            best = max(best, t.value)
        else:
            x = x_of(t.number)
            parts.append(f'<text x="{x:.1f}" y="{bottom - 4}" text-anchor="middle" fill="#d62728">×</text>')
        if math.isfinite(best):
            best_line.append(f"{x_of(t.number):.1f},{y_of(best):.1f}")
    if best_line:
        parts.append(f'<polyline points="{" ".join(best_line)}" fill="none" stroke="#ff7f0e" stroke-width="2"/>')
    for k in range(0, n, max(1, n // 10)):
        parts.append(f'<text x="{x_of(k):.1f}" y="{bottom + 15}" text-anchor="middle">{k}</text>')
    parts.append(f'<text x="{left + w / 2}" y="{bottom + 32}" text-anchor="middle">trial (×: pruned or failed)</text>')
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    x0 = left + w + 90
    parts.append(f'<rect x="{x0}" y="{top}" width="{w}" height="{h}" fill="none" stroke="black"/>')
    if complete:
        best_trial = study.best_trial
        per = best_trial.user_attrs.get("per_condition", {})
        keys = sorted(per)
        advances = [float(baselines[k].get("advance_at_rest_m") or "nan") for k in keys if k in baselines]
        mine = [per[k]["advance_at_rest_m"] for k in keys]
        finite = [v for v in advances + mine if v is not None and math.isfinite(v)]
        a_lo, a_hi = min(finite + [0.0]), max(finite + [0.1])
        a_lo, a_hi = a_lo - 0.1 * (a_hi - a_lo), a_hi + 0.1 * (a_hi - a_lo)
        for frac in (0.0, 0.5, 1.0):
            v = a_lo + frac * (a_hi - a_lo)
            parts.append(f'<text x="{x0 - 5}" y="{bottom - frac * h + 4:.1f}" text-anchor="end">{v:.2f}</text>')
        parts.append(f'<text x="{x0 + w / 2}" y="{top - 8}" text-anchor="middle">advance at rest (m), best trial '
                     f'{best_trial.number} (orange) against feedforward (grey)</text>')
        slot = w / max(len(keys), 1)
        for i, key in enumerate(keys):
            for j, value in enumerate((advances[i] if i < len(advances) else math.nan, mine[i])):
                if value is None or not math.isfinite(value):
                    continue
                y0 = bottom - (0.0 - a_lo) / (a_hi - a_lo) * h
                y1 = bottom - (value - a_lo) / (a_hi - a_lo) * h
                x = x0 + slot * i + slot * (0.15 + 0.35 * j)
                parts.append(f'<rect x="{x:.1f}" y="{min(y0, y1):.1f}" width="{slot * 0.3:.1f}" '
                             f'height="{abs(y1 - y0):.1f}" fill="{"#999999" if j == 0 else "#ff7f0e"}"/>')
            parts.append(f'<text x="{x0 + slot * (i + 0.5):.1f}" y="{bottom + 14}" text-anchor="middle" '
                         f'font-size="9">{key.replace("&", "&amp;")}</text>')
    parts.append("</svg>")
    return "\n".join(parts)

