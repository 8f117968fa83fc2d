"""Pre-registered evaluation of controllers against feedforward (``sensnake experiment evaluate EVAL.toml --out DIR``).

An evaluation file fixes, before any run, everything that decides the result: the scene *families* conditions are
drawn from and the ranges of each of their parameters, how many conditions each family gives, the seed of the draw,
how many run seeds each condition is played with (at least :data:`MIN_SEEDS`), the controllers, the motion, and the
statistics. The draw is a function of the file alone, so the file (its SHA-256 is in the report) *is* the
evaluation: a changed file is a new evaluation, and a folder holding one evaluation refuses runs of another.

Families (``[[family]] kind``), each obstacle centred at x = 0 with the head ``0.44 m + start offset`` ahead of it
(the paper's start: segment 6 over the obstacle), the robot dropped limp and settled, its drape captured, scaled and
played follow-the-leader:

=================  ===================================================================================================
``half_cylinder``  one half cylinder, radius ``height_m``
``step``           a box (a platform the body drapes over), ``height_m`` high and ``length_m`` long
``wedge``          a ramp rising toward +x over ``length_m`` to ``height_m``, then a drop
``bumps``          ``count`` half cylinders of radius ``height_m``, ``spacing_m`` apart, centred on x = 0
=================  ===================================================================================================

and in every family: the cover's ``friction`` and ``roll_resistance_m`` (the obstacles'), ``ground_friction``,
``tail_load_n``, ``shape_scale`` (the captured drape's angles times it) and ``start_offset_m``. A parameter is a
number (fixed) or ``[low, high]`` (drawn uniformly; ``count`` a whole number in it).

Each condition is run with ``seeds_per_condition`` run seeds (drawn too; a run seed also jitters the start and the
frictions, :func:`app.core.experiment.jittered_scene`, and the sensors' noise), and every controller and
feedforward play the same (condition, seed): a *pair*. A pair with an invalid run is left out and counted; a pair
with a run undecided at rest is left out of the traversal and advance statistics and counted. Statistics, per family
and overall, of each controller against feedforward on its pairs: traversal probability at rest, advance at rest
(m), overload events per run; each a difference with a paired bootstrap interval that resamples *conditions* (the
seeds of one condition are not independent), with ``bootstrap`` resamples; the overall row resamples all the
conditions together (not family by family), so a resample may hold more of one family than the draw did.

Qt-free: the figure is SVG; the command line rasterises the PNG.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from app.core.engines import (
    MAX_RUNS,
    FolderLock,
    RunJournal,
    Task,
    capped_jobs,
    capped_words,
    check_scheduler,
    open_engine,
    read_folder_record,
)
from app.core.errors import EvaluationError, RunsInterrupted
from app.core.outputs import replace_text, replacing_text
from app.core.sweep import SUMMARY_COLUMNS, execute, is_invalid, write_summary
from devices.toml_files import read_toml_file
from models.controllers import CONTROLLERS, FEEDFORWARD
from models.errors import GainsError
from models.force_feedback import FeedbackGains

MIN_SEEDS = 10
KINDS = ("half_cylinder", "step", "wedge", "bumps")
HEAD_AHEAD_M = 0.44  # the paper's start: 5.5 segments of 0.08 m ahead of the obstacle's centre
# Each family's parameters and their default ranges (a file may fix or narrow each one).
COMMON_RANGES: dict[str, tuple[float, float]] = {
    "friction": (0.05, 0.3), "roll_resistance_m": (0.004, 0.012), "ground_friction": (0.25, 0.35),
    "tail_load_n": (0.0, 1.5), "shape_scale": (0.9, 1.1), "start_offset_m": (-0.03, 0.03)}
KIND_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "half_cylinder": {"height_m": (0.15, 0.30)},
    # lower steps, wedges and bumps settle nearly straight under the body: nothing to propagate (measured)
    "step": {"height_m": (0.12, 0.22), "length_m": (0.15, 0.3)},
    "wedge": {"height_m": (0.12, 0.22), "length_m": (0.3, 0.5)},
    "bumps": {"height_m": (0.08, 0.13), "count": (2, 3), "spacing_m": (0.3, 0.45)},
}
# What a parameter may be at all (a file's range must lie within).
LIMITS: dict[str, tuple[float, float]] = {
    "friction": (0.0, 2.0), "roll_resistance_m": (0.0, 0.036), "ground_friction": (0.05, 2.0),
    "tail_load_n": (0.0, 30.0), "shape_scale": (0.1, 2.0), "start_offset_m": (-0.2, 0.2), "height_m": (0.01, 0.5),
    "length_m": (0.05, 1.5), "count": (1, 12), "spacing_m": (0.08, 1.0)}
EVAL_KEYS = {"seed", "seeds_per_condition", "controllers", "gains", "seconds", "speed_rad_s", "settle_s",
             "rest_cap_s", "repeat", "bootstrap", "confidence", "family", "note"}
METRICS = (("traversal", "probability"), ("advance_at_rest", "m"), ("overloads", "events per run"))
EVALUATION_COLUMNS = ("family", "controller", "metric", "unit", "pairs", "conditions", "feedforward", "candidate",
                      "difference", "ci_low", "ci_high", "invalid_pairs", "undecided_pairs")


@dataclass(frozen=True)
class Family:
    kind: str
    conditions: int
    ranges: dict[str, tuple[float, float]]  # every parameter, (value, value) when fixed
    name: str = ""


@dataclass(frozen=True)
class Condition:
    """One drawn condition: its scene's text, tail load, shape scaling and the run seeds it is played with."""

    index: int
    family: str
    kind: str
    values: dict[str, float]
    scene_text: str
    tail_load_n: float
    shape_scale: float
    seeds: tuple[int, ...]


@dataclass(frozen=True)
class EvaluationPlan:
    path: Path
    sha256: str
    text: str
    seed: int
    seeds_per_condition: int
    controllers: tuple[str, ...]
    gains: FeedbackGains
    families: tuple[Family, ...]
    seconds: float = 40.0
    speed_rad_s: float = 0.1
    settle_s: float = 6.0
    rest_cap_s: float = 30.0
    repeat: int = 1
    bootstrap: int = 2000
    confidence: float = 0.95
    conditions: tuple[Condition, ...] = field(default=())

    @property
    def runs(self) -> int:
        return len(self.conditions) * self.seeds_per_condition * (1 + len(self.controllers))


def read_evaluation(path: str | Path) -> EvaluationPlan:
    """Read and check an evaluation file and draw its conditions; :class:`EvaluationError` names the file and key."""
    path = Path(path)
    text, data = read_toml_file(path, "evaluation file", EvaluationError)
    sha = hashlib.sha256(text.encode("utf-8")).hexdigest()
    for key in data:
        if key not in EVAL_KEYS:
            raise EvaluationError(f"{path}: unknown key '{key}' (known: {', '.join(sorted(EVAL_KEYS))})")
    seed = data.get("seed")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise EvaluationError(f"{path}: 'seed' (the draw's seed, written before any run) must be a whole number ≥ 0, "
                              f"got {seed!r}")
    seeds = data.get("seeds_per_condition", MIN_SEEDS)
    if isinstance(seeds, bool) or not isinstance(seeds, int) or not MIN_SEEDS <= seeds <= 1000:
        raise EvaluationError(f"{path}: 'seeds_per_condition' must be a whole number {MIN_SEEDS} … 1000, got "
                              f"{seeds!r}")
    controllers = data.get("controllers", ["feedback"])
    if not isinstance(controllers, list) or not controllers or any(
            c not in CONTROLLERS or c == FEEDFORWARD for c in controllers) or len(set(controllers)) != len(controllers):
        raise EvaluationError(f"{path}: 'controllers' must list some of "
                              f"{', '.join(c for c in CONTROLLERS if c != FEEDFORWARD)} (each once; each is paired "
                              f"with feedforward), got {controllers!r}")
    table = data.get("gains", {})
    if not isinstance(table, dict):
        raise EvaluationError(f"{path}: [gains] must be a table of the law's gains")
    try:
        gains = FeedbackGains.from_mapping(table, f"{path} [gains]")
    except GainsError as exc:
        raise EvaluationError(str(exc)) from None
    scalars: dict[str, Any] = {}
    for key, default, low, high in (("seconds", 40.0, 0.5, 3600.0), ("speed_rad_s", 0.1, 0.001, 1.0),
                                    ("settle_s", 6.0, 0.0, 60.0), ("rest_cap_s", 30.0, 0.0, 600.0),
                                    ("confidence", 0.95, 0.5, 0.999)):
        value = data.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
            raise EvaluationError(f"{path}: '{key}' must be a number in [{low:g}, {high:g}], got {value!r}")
        scalars[key] = float(value)
    for key, default, low, high in (("repeat", 1, 1, 100), ("bootstrap", 2000, 100, 100_000)):
        value = data.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise EvaluationError(f"{path}: '{key}' must be a whole number {low} … {high}, got {value!r}")
        scalars[key] = value
    raw = data.get("family", [])
    if not isinstance(raw, list) or not raw or not all(isinstance(f, dict) for f in raw):
        raise EvaluationError(f"{path}: give at least one [[family]] table (kind = one of {', '.join(KINDS)})")
    families = tuple(_family(path, k, table) for k, table in enumerate(raw, start=1))
    names = [f.name for f in families]
    if len(set(names)) != len(names):
        raise EvaluationError(f"{path}: two [[family]] tables share the name {sorted(n for n in names if names.count(n) > 1)[0]!r}: "
                              "give each its own 'name'")
    plan = EvaluationPlan(path=path, sha256=sha, text=text, seed=seed, seeds_per_condition=seeds,
                          controllers=tuple(controllers), gains=gains, families=families, **scalars)
    plan = replace(plan, conditions=draw_conditions(plan))
    if plan.runs > MAX_RUNS:
        raise EvaluationError(f"{path}: {plan.runs} runs (conditions × seeds × (controllers + feedforward)); an "
                              f"evaluation holds at most {MAX_RUNS}")
    _refuse_unholdable(plan)
    return plan


def _family(path: Path, k: int, table: dict[str, Any]) -> Family:
    where = f"{path} [[family]] #{k}"
    kind = table.get("kind")
    if kind not in KINDS:
        raise EvaluationError(f"{where}: 'kind' must be one of {', '.join(KINDS)}, got {kind!r}")
    defaults = {**COMMON_RANGES, **KIND_RANGES[kind]}
    allowed = set(defaults) | {"kind", "conditions", "name"}
    for key in table:
        if key not in allowed:
            raise EvaluationError(f"{where}: unknown key '{key}' for kind {kind} (known: {', '.join(sorted(allowed))})")
    conditions = table.get("conditions", 1)
    if isinstance(conditions, bool) or not isinstance(conditions, int) or not 1 <= conditions <= 1000:
        raise EvaluationError(f"{where}: 'conditions' must be a whole number 1 … 1000, got {conditions!r}")
    name = table.get("name", kind)
    if not isinstance(name, str) or not name or not name.replace("_", "").replace("-", "").isalnum():
        raise EvaluationError(f"{where}: 'name' must be letters, digits, '-' or '_', got {name!r}")
    ranges = {}
    for key, default in defaults.items():
        value = table.get(key, list(default))
        if isinstance(value, int | float) and not isinstance(value, bool):
            value = [value, value]
        if not (isinstance(value, list) and len(value) == 2 and all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
            raise EvaluationError(f"{where}: '{key}' must be a number or [low, high], got {value!r}")
        low, high = float(value[0]), float(value[1])
        lo_limit, hi_limit = LIMITS[key]
        if not lo_limit <= low <= high <= hi_limit:
            raise EvaluationError(f"{where}: '{key}' = [{low:g}, {high:g}] must satisfy {lo_limit:g} ≤ low ≤ high ≤ "
                                  f"{hi_limit:g}")
        if key == "count" and (low != int(low) or high != int(high)):
            raise EvaluationError(f"{where}: 'count' must be whole numbers, got {value!r}")
        ranges[key] = (low, high)
    return Family(kind, conditions, ranges, name)


def draw_conditions(plan: EvaluationPlan) -> tuple[Condition, ...]:
    """The conditions the file draws: families in order, each parameter in a fixed order, from ``plan.seed``."""
    rng = np.random.default_rng(plan.seed)
    out: list[Condition] = []
    for family in plan.families:
        for _ in range(family.conditions):
            values = {}
            for key in sorted(family.ranges):
                low, high = family.ranges[key]
                values[key] = float(rng.integers(int(low), int(high) + 1)) if key == "count" else \
                    float(round(rng.uniform(low, high), 6))
            seeds: list[int] = []
            while len(seeds) < plan.seeds_per_condition:  # distinct run seeds ≥ 1
                seed = int(rng.integers(1, 2**31 - 1))
                if seed not in seeds:
                    seeds.append(seed)
            out.append(Condition(len(out), family.name, family.kind, values, scene_text(family.kind, values),
                                 values["tail_load_n"], values["shape_scale"], tuple(seeds)))
    return tuple(out)


def scene_text(kind: str, values: dict[str, float]) -> str:
    """The scene file (SPEC §6) of a drawn condition."""
    height, friction, roll = values["height_m"], values["friction"], values["roll_resistance_m"]
    obstacles: list[list[str]] = []
    if kind == "half_cylinder":
        obstacles.append(['shape = "half_cylinder"', "x_m = 0.0", f"radius_m = {height!r}"])
    elif kind in ("step", "wedge"):
        obstacles.append([f'shape = "{"box" if kind == "step" else "wedge"}"', "x_m = 0.0",
                          f"length_m = {values['length_m']!r}", f"height_m = {height!r}"])
    else:
        count = int(values["count"])
        for i in range(count):
            x = round((i - (count - 1) / 2) * values["spacing_m"], 6)
            obstacles.append(['shape = "half_cylinder"', f"x_m = {x!r}", f"radius_m = {height!r}"])
    lines = [f"# drawn by an evaluation: {kind}, " + ", ".join(f"{k} = {v:g}" for k, v in sorted(values.items())),
             "[ground]", f"friction = {values['ground_friction']!r}"]
    for body in obstacles:
        lines += ["", "[[obstacle]]", *body, f"friction = {friction!r}", f"roll_resistance_m = {roll!r}"]
    lines += ["", "[robot]", f"head_x_m = {round(HEAD_AHEAD_M + values['start_offset_m'], 6)!r}", 'start = "settle"']
    return "\n".join(lines) + "\n"


def _refuse_unholdable(plan: EvaluationPlan) -> None:
    """A drawn tail load friction cannot hold on its scene, at any of its run seeds' frictions: refused before any
    run, naming the family and the formula."""
    from app.core.experiment import jittered_scene
    from devices.errors import SceneError
    from devices.scene import parse_scene

    for condition in plan.conditions:
        try:
            scene = parse_scene(condition.scene_text, f"{plan.path} family {condition.family}",
                                name=f"{condition.family}-{condition.index}")
            for seed in condition.seeds:
                jittered_scene(scene, seed).refuse_unholdable_load(
                    condition.tail_load_n, f"'tail_load_n' (family {condition.family}, seed {seed})")
        except SceneError as exc:
            raise EvaluationError(f"{plan.path}: {exc}") from None


def evaluation_tasks(plan: EvaluationPlan, out: Path) -> list[Task]:
    """One task per (condition, seed, controller), feedforward first, with the condition's scene file in
    ``out/scenes``."""
    scenes = out / "scenes"
    tasks: list[Task] = []
    for condition in plan.conditions:
        scene_path = scenes / f"{condition.index:03d}_{condition.family}.toml"
        for seed in condition.seeds:
            for controller in (FEEDFORWARD, *plan.controllers):
                k = len(tasks)
                law = controller != FEEDFORWARD
                tasks.append({"run": k, "scene": str(scene_path.resolve()), "controller": controller,
                              "gains_index": 0 if law else -1, "gains": plan.gains if law else None,
                              "tail_load_n": condition.tail_load_n, "seed": seed, "mode": "follow",
                              "seconds": plan.seconds, "speed_rad_s": plan.speed_rad_s, "settle_s": plan.settle_s,
                              "repeat": plan.repeat, "rest_cap_s": plan.rest_cap_s,
                              "shape_scale": condition.shape_scale, "plan_name": "experiment evaluate",
                              "condition": condition.index, "family": condition.family,
                              "out": str((out / f"{k:05d}_{condition.family}{condition.index}_{controller}_seed{seed}"
                                                f".h5").resolve())})
    return tasks


def run_evaluation(plan: EvaluationPlan, out_dir: str | Path, *, jobs: int | None = None, engine: str = "local",
                   scheduler: str | None = None, progress: Callable[[str], None] | None = None,
                   say: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Run ``plan`` into ``out_dir`` (resuming one cut short there; refusing a folder of another file's evaluation)
    and write the report. Returns the rows of ``evaluation.csv``."""
    check_scheduler(scheduler if engine == "dask" else None)  # before anything is written
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with FolderLock(out, "evaluation"):
        record = out / "evaluation.json"
        resumed = record.exists()
        if resumed:
            held = read_folder_record(record, "evaluation folder's record", EvaluationError)
            if held.get("sha256") != plan.sha256:
                raise EvaluationError(f"{out}: holds the evaluation of another file (sha256 {str(held.get('sha256'))[:16]}…, "
                                      f"this file's {plan.sha256[:16]}…): a changed file is a new evaluation; "
                                      "choose another --out folder")
            if (out / "evaluation.csv").exists() and len(RunJournal(out).load()) >= plan.runs:
                raise EvaluationError(f"{out}: holds this evaluation already, finished (evaluation.csv); choose "
                                      "another --out folder")
        elif any(out.iterdir()) and set(p.name for p in out.iterdir()) != {".lock"}:
            raise EvaluationError(f"{out}: not empty and holds no evaluation; choose a new --out folder")
        else:
            replace_text(out / "evaluation.file.toml", plan.text)
            replace_text(record, json.dumps({"kind": "evaluation", "sha256": plan.sha256, "file": str(plan.path),
                                             "runs": plan.runs, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")},
                                            indent=1))
        scenes = out / "scenes"
        scenes.mkdir(exist_ok=True)
        for condition in plan.conditions:
            replace_text(scenes / f"{condition.index:03d}_{condition.family}.toml", condition.scene_text)
        _write_conditions(out, plan)
        tasks = evaluation_tasks(plan, out)
        journal = RunJournal(out)
        finished = len(journal.load())
        width = capped_jobs(jobs, len(tasks) - finished)
        runner = open_engine(engine, width, scheduler)
        if say is not None:
            say(f"evaluation {plan.path.name} (sha256 {plan.sha256[:16]}…): {len(plan.conditions)} conditions × "
                f"{plan.seeds_per_condition} seeds × {1 + len(plan.controllers)} controllers = {len(tasks)} runs"
                + (f", {finished} finished before (resuming)" if resumed and finished else "")
                + f", on {runner.description}{capped_words(jobs, width)}")
        try:
            rows, failures = execute(tasks, runner, journal, progress)
        except RunsInterrupted as stop:
            done = journal.load()
            stop.finished, stop.total = len(done), len(tasks)
            _write_runs(out, tasks, done)
            raise
        finally:
            runner.close()
        write_summary(out, [rows[k] for k in sorted(rows)], failures, tasks)
        (out / "summary.svg").unlink(missing_ok=True)  # the evaluation's figure is its own (below)
        (out / "summary.csv").unlink(missing_ok=True)  # runs.csv carries the rows with their condition
        _write_runs(out, tasks, rows)
        table = evaluate_rows(plan, tasks, rows)
        with replacing_text(out / "evaluation.csv") as f:
            f.write(f"# evaluation file {plan.path.name} sha256 {plan.sha256}\n")
            writer = csv.DictWriter(f, fieldnames=EVALUATION_COLUMNS)
            writer.writeheader()
            writer.writerows(table)
        record_data = json.loads(record.read_text(encoding="utf-8"))
        record_data.update({"finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "failed_runs": len(failures),
                            "invalid_runs": sum(1 for r in rows.values() if is_invalid(r))})
        replace_text(record, json.dumps(record_data, indent=1))
        replace_text(out / "evaluation.svg", evaluation_svg(table, plan))
    return table


def _write_conditions(out: Path, plan: EvaluationPlan) -> None:
    keys = sorted({k for c in plan.conditions for k in c.values})
    with replacing_text(out / "conditions.csv") as f:
        writer = csv.writer(f)
        writer.writerow(["condition", "family", "kind", "scene", *keys, "seeds"])
        for c in plan.conditions:
            writer.writerow([c.index, c.family, c.kind, f"scenes/{c.index:03d}_{c.family}.toml",
                             *[c.values.get(k, "") for k in keys], " ".join(str(s) for s in c.seeds)])


def _write_runs(out: Path, tasks: list[Task], rows: dict[int, dict[str, Any]]) -> None:
    columns = ("family", "condition", "shape_scale", *SUMMARY_COLUMNS)
    with replacing_text(out / "runs.csv") as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for k in sorted(rows):
            task = tasks[k]
            writer.writerow({**rows[k], "family": task["family"], "condition": task["condition"],
                             "shape_scale": task["shape_scale"]})


# -- statistics ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Pair:
    family: str
    condition: int
    ff: dict[str, Any]
    candidate: dict[str, Any]


def _number(row: dict[str, Any], key: str) -> float:
    text = str(row.get(key, ""))
    return float(text) if text not in ("", "nan") else math.nan


def _finished(row: dict[str, Any] | None) -> bool:
    return row is not None and (row.get("traversed", "") != "" or is_invalid(row))


def evaluate_rows(plan: EvaluationPlan, tasks: Sequence[Task], rows: dict[int, dict[str, Any]]
                  ) -> list[dict[str, Any]]:
    """``evaluation.csv``'s rows: per family (and ``all``) × controller × metric, the paired difference against
    feedforward with its bootstrap interval, and the pairs left out (invalid; undecided)."""
    by_key: dict[tuple[int, int, str], dict[str, Any]] = {}
    for task in tasks:
        row = rows.get(task["run"])
        if _finished(row):
            assert row is not None
            by_key[(task["condition"], task["seed"], task["controller"])] = row
    families = [f.name for f in plan.families]
    rng_seed = plan.seed
    table = []
    for controller in plan.controllers:
        pairs: list[Pair] = []
        invalid: dict[str, int] = dict.fromkeys(families, 0)
        for condition in plan.conditions:
            for seed in condition.seeds:
                ff = by_key.get((condition.index, seed, FEEDFORWARD))
                cand = by_key.get((condition.index, seed, controller))
                if ff is None or cand is None:
                    continue  # a failed run: in failures.csv, no pair
                if is_invalid(ff) or is_invalid(cand):
                    invalid[condition.family] += 1
                    continue
                pairs.append(Pair(condition.family, condition.index, ff, cand))
        for family in [*families, "all"]:
            chosen = [p for p in pairs if family in ("all", p.family)]
            left_invalid = sum(invalid.values()) if family == "all" else invalid[family]
            for metric, unit in METRICS:
                values, undecided = _paired_values(chosen, metric)
                entry = _interval(values, plan.bootstrap, plan.confidence, rng_seed)
                table.append({"family": family, "controller": controller, "metric": metric, "unit": unit,
                              "pairs": len(values), "conditions": len({c for c, _, _ in values}),
                              **entry, "invalid_pairs": left_invalid, "undecided_pairs": undecided})
    return table


def _paired_values(pairs: list[Pair], metric: str) -> tuple[list[tuple[int, float, float]], int]:
    """(condition, feedforward's value, the candidate's) per pair usable for ``metric``, and how many pairs were
    left out as undecided at rest."""
    values = []
    undecided = 0
    for pair in pairs:
        if metric == "overloads":
            values.append((pair.condition, _number(pair.ff, "overloads"), _number(pair.candidate, "overloads")))
            continue
        outcomes = (str(pair.ff.get("outcome", "")), str(pair.candidate.get("outcome", "")))
        if "undecided" in outcomes or "" in outcomes:
            undecided += 1
            continue
        if metric == "traversal":
            values.append((pair.condition, float(outcomes[0] == "traversed"), float(outcomes[1] == "traversed")))
        else:
            values.append((pair.condition, _number(pair.ff, "advance_at_rest_m"),
                           _number(pair.candidate, "advance_at_rest_m")))
    return values, undecided


def _interval(values: list[tuple[int, float, float]], resamples: int, confidence: float, seed: int
              ) -> dict[str, float]:
    """Means of feedforward and the candidate, the mean paired difference, and its percentile interval over
    ``resamples`` bootstrap resamples of the conditions (with replacement; the pairs of a drawn condition all). With
    fewer than two conditions there is no interval (NaN): the seeds of one condition are not independent."""
    if not values:
        return dict.fromkeys(("feedforward", "candidate", "difference", "ci_low", "ci_high"), math.nan)
    conditions = sorted({c for c, _, _ in values})
    index = {c: i for i, c in enumerate(conditions)}
    sums = np.zeros(len(conditions))
    counts = np.zeros(len(conditions))
    for c, ff, cand in values:
        sums[index[c]] += cand - ff
        counts[index[c]] += 1
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(conditions), size=(resamples, len(conditions)))
    means = sums[draws].sum(axis=1) / counts[draws].sum(axis=1)
    tail = (1.0 - confidence) / 2.0
    if len(conditions) < 2:  # one condition: resampling conditions says nothing about its spread (no interval)
        return {"feedforward": float(np.mean([ff for _, ff, _ in values])),
                "candidate": float(np.mean([cand for _, _, cand in values])),
                "difference": float(sums.sum() / counts.sum()), "ci_low": math.nan, "ci_high": math.nan}
    return {"feedforward": float(np.mean([ff for _, ff, _ in values])),
            "candidate": float(np.mean([cand for _, _, cand in values])),
            "difference": float(sums.sum() / counts.sum()),
            "ci_low": float(np.quantile(means, tail)), "ci_high": float(np.quantile(means, 1.0 - tail))}


def read_evaluation_table(path: str | Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


# -- the figure ------------------------------------------------------------------------------------------------------
_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd")


def evaluation_svg(table: list[dict[str, Any]], plan: EvaluationPlan) -> str:
    """One panel per metric: each controller's paired difference against feedforward with its interval, per family
    and overall (the zero line: no difference)."""
    families = [f.name for f in plan.families] + ["all"]
    controllers = list(plan.controllers)
    panel_w, panel_h, left, top, gap = 300.0, 260.0, 70.0, 60.0, 60.0
    width = int(left + len(METRICS) * (panel_w + gap) + 150)
    height = int(top + panel_h + 90)
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" '
             f'font-size="12"><rect width="100%" height="100%" fill="white"/>',
             f'<text x="{left}" y="18">evaluation {_escape(plan.path.name)} (sha256 {plan.sha256[:16]}…): '
             f'controller − feedforward, paired, {100 * plan.confidence:g} % bootstrap intervals over conditions</text>']
    for m, (metric, unit) in enumerate(METRICS):
        entries = [e for e in table if e["metric"] == metric]
        finite = [v for e in entries for v in (e["ci_low"], e["ci_high"], e["difference"]) if math.isfinite(v)]
        lo, hi = min(finite + [0.0]), max(finite + [0.0])
        if hi - lo < 1e-9:
            lo, hi = lo - 1.0, hi + 1.0
        pad = 0.08 * (hi - lo)
        lo, hi = lo - pad, hi + pad
        x0 = left + m * (panel_w + gap)
        bottom = top + panel_h

        def y_of(v: float, lo: float = lo, hi: float = hi, bottom: float = bottom) -> float:
            return bottom - (v - lo) / (hi - lo) * panel_h

        parts.append(f'<text x="{x0 + panel_w / 2}" y="{top - 12}" text-anchor="middle">{metric} ({unit})</text>')
        parts.append(f'<rect x="{x0}" y="{top}" width="{panel_w}" height="{panel_h}" fill="none" stroke="black"/>')
        parts.append(f'<line x1="{x0}" y1="{y_of(0.0):.1f}" x2="{x0 + panel_w}" y2="{y_of(0.0):.1f}" '
                     f'stroke="#888888" stroke-dasharray="4 3"/>')
        for frac in (0.0, 0.5, 1.0):
            v = lo + frac * (hi - lo)
            parts.append(f'<text x="{x0 - 5}" y="{y_of(v) + 4:.1f}" text-anchor="end">{v:.2g}</text>')
        slot = panel_w / len(families)
        for f_index, family in enumerate(families):
            cx = x0 + slot * (f_index + 0.5)
            parts.append(f'<text x="{cx:.1f}" y="{bottom + 16}" text-anchor="middle">{_escape(family)}</text>')
            for c_index, controller in enumerate(controllers):
                entry = next((e for e in entries if e["family"] == family and e["controller"] == controller), None)
                if entry is None or not math.isfinite(entry["difference"]):
                    continue
                x = cx + (c_index - (len(controllers) - 1) / 2) * 10
                colour = _COLOURS[c_index % len(_COLOURS)]
                parts.append(f'<line x1="{x:.1f}" y1="{y_of(entry["ci_low"]):.1f}" x2="{x:.1f}" '
                             f'y2="{y_of(entry["ci_high"]):.1f}" stroke="{colour}" stroke-width="2"/>')
                parts.append(f'<circle cx="{x:.1f}" cy="{y_of(entry["difference"]):.1f}" r="4" fill="{colour}"/>')
    for c_index, controller in enumerate(controllers):
        y = top + 16 * c_index
        x = left + len(METRICS) * (panel_w + gap) - 20
        parts.append(f'<circle cx="{x}" cy="{y - 4}" r="4" fill="{_COLOURS[c_index % len(_COLOURS)]}"/>')
        parts.append(f'<text x="{x + 10}" y="{y}">{_escape(controller)}</text>')
    parts.append("</svg>")
    return "\n".join(parts)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def gains_text(gains: FeedbackGains) -> str:
    """The gains as a gains file's ``[feedback]`` table."""
    return "[feedback]\n" + "".join(f"{k} = {v!r}\n" for k, v in asdict(gains).items())
