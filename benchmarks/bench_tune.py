"""A timed tuning: ``sensnake experiment tune`` from an empty folder to the end of its report, measured from outside.

The tuning file is ``benchmarks/tune_feedback_families.toml`` (committed before any run of it: 4 training conditions —
two half cylinders and two rows of bumps, 1.0 N, run seed 47 — and 6 test conditions on six other new scenes of
those families; ``--plan`` takes another). The command runs as its own process (``python -m app experiment tune FILE
--trials N --out DIR --jobs J``), so what is measured is what a user waits for: the feedforward baselines, N trials
(each one gain set on the 4 training conditions, pruned part-way when behind the median), and the report (the best
and the default gains on the test conditions). Printed and written to ``benchmarks/results/bench_tune.txt``
(``--write``):

* wall seconds end to end, and per trial (the trials' own ``duration_s`` from ``trials.csv``: mean, median, max;
  and the wall time outside the trials: baselines, test runs, start-up);
* the command's CPU seconds (user + system of it and its worker processes, ``os.wait4``) and its peak resident memory
  (the largest single process);
* **the machine's load while it ran**: the 1-minute load average sampled every 5 s (min / mean / max) and the cores
  the *other* processes on the machine used on average (all CPU time in ``/proc/stat`` over the run, less the
  command's own), since other engineers share these cores;
* trials complete / pruned / failed, and ``report.csv``'s rows: the best gains' and today's defaults' train and test
  scores against feedforward.

``--conditions DIR`` runs nothing: it reads a finished study and writes each condition's score for the best and the
default gains (``DIR/per_condition.csv``), and prints the mean and median score of each gain set and split with 95 %
bootstrap intervals over the conditions, and the best gains against the defaults on the test conditions.

Measured (2026-12-05, ``nice -n 10 python -m benchmarks.bench_tune --trials 40 --jobs 1 --write``, the 2 cores shared
with other engineers' work: 1-minute load 1.4–14.7, mean 8.4; the others used 1.49 cores on average): 40 trials (11
complete, 29 pruned) and the report in **33.4 min of wall**, 853 s of CPU, median 22 s a trial. On the test
conditions (5 of 6 decided) the best gains score −0.03 cm in the median, −1.3 cm in the mean [−3.5, +0.2], against
today's defaults' +0.02 cm and +0.2 cm [−0.2, +0.7]; best minus defaults −1.5 cm [−4.3, +0.3]: the tuner does not beat
the defaults, which stay, and neither beats feedforward (docs/FORCE_FEEDBACK.md; the study and its report in
``benchmarks/results/tune_feedback_families/``).

Run: ``nice -n 10 python -m benchmarks.bench_tune [--trials 40] [--jobs 1] [--out DIR] [--write]`` (start it under
``nohup`` and read the log). ``--out`` must be a new folder (the time of a study started from nothing); the study,
``trials.csv``, ``report.csv``, ``best_gains.toml`` and the figure stay in it. A study cut short (SIGTERM: exit 130,
the cut trial tried again) continues with ``--resume`` (the same ``--out``; ``--trials`` as many as it holds only
reports). ``sensnake bench --quick`` runs 3 trials into a temporary folder.
"""

from __future__ import annotations

import argparse
import csv
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
PLAN = ROOT / "benchmarks" / "tune_feedback_families.toml"
RESULTS = ROOT / "benchmarks" / "results" / "bench_tune.txt"
LOAD_SAMPLE_S = 5.0


def _cpu_ticks() -> tuple[int, int]:
    """(busy, total) jiffies of every core from /proc/stat's first line."""
    fields = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
    return sum(fields) - idle, sum(fields)


class LoadWatch:
    """The 1-minute load average every :data:`LOAD_SAMPLE_S` seconds, and the machine's busy CPU seconds, while a
    command runs."""

    def __init__(self) -> None:
        self.samples: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True, name="load-watch")
        self._start_ticks = _cpu_ticks()
        self.busy_s = 0.0

    def _watch(self) -> None:
        while not self._stop.is_set():
            self.samples.append(float(Path("/proc/loadavg").read_text().split()[0]))
            self._stop.wait(LOAD_SAMPLE_S)

    def __enter__(self) -> LoadWatch:
        self._start_ticks = _cpu_ticks()
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=LOAD_SAMPLE_S + 1)
        busy, _ = _cpu_ticks()
        self.busy_s = (busy - self._start_ticks[0]) / os.sysconf("SC_CLK_TCK")


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def _f(text: str, fmt: str = "+.3f") -> str:
    try:
        value = float(text)
    except ValueError:
        return "—"
    return "—" if value != value else format(value, fmt)


def time_tune(plan: Path, trials: int, jobs: int, out: Path, resume: bool = False) -> dict:
    """Run the tuning once into the new folder ``out`` (``resume``: the study already in it, continued or, with as
    many trials as it holds, only reported) and measure it."""
    if not resume and out.exists() and any(out.iterdir()):
        raise SystemExit(f"bench_tune: {out} is not empty: the benchmark times a study started from nothing; "
                         "choose a new --out folder")
    out.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, "-m", "app", "experiment", "tune", str(plan), "--trials", str(trials), "--out",
               str(out), "--jobs", str(jobs)]
    log = out.parent / f"{out.name}{'.resumed' if resume else ''}.log"
    load_before = Path("/proc/loadavg").read_text().split()[:3]
    started_at = time.strftime("%Y-%m-%d %H:%M:%S %z")
    with open(log, "w", encoding="utf-8") as sink, LoadWatch() as watch:
        start = time.perf_counter()
        child = subprocess.Popen(command, cwd=ROOT, stdout=sink, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - start
    code = os.waitstatus_to_exitcode(status)
    cpu = usage.ru_utime + usage.ru_stime
    result = {"command": " ".join(["sensnake", *command[3:]]).replace(str(ROOT) + "/", ""), "started": started_at,
              "exit": code, "wall_s": wall, "cpu_s": cpu, "peak_rss_mb": usage.ru_maxrss / 1024.0,
              "load_before": load_before, "load": watch.samples, "others_cores": max(0.0, watch.busy_s - cpu) / wall,
              "cores": os.cpu_count() or 1, "jobs": jobs, "log": log, "out": out, "trials": [], "report": [],
              "resumed": resume}
    if (out / "trials.csv").exists():
        result["trials"] = _rows(out / "trials.csv")
    if (out / "report.csv").exists():
        result["report"] = _rows(out / "report.csv")
    return result


def summary(r: dict) -> list[str]:
    """The lines printed and written to the results file."""
    trials = r["trials"]
    states = {s: sum(t["state"] == s for t in trials) for s in ("complete", "pruned", "fail", "waiting")}
    durations = [float(t["duration_s"]) for t in trials if t.get("duration_s")]
    complete = [float(t["duration_s"]) for t in trials if t["state"] == "complete" and t.get("duration_s")]
    load = r["load"] or [float("nan")]
    outside = r["wall_s"] - sum(durations)
    lines = [
        f"# bench_tune: {r['command']}",
        f"started {r['started']} on {r['cores']} cores, --jobs {r['jobs']}; exit {r['exit']}",
        f"wall {r['wall_s']:.0f} s ({r['wall_s'] / 60:.1f} min) for {len(trials)} trials: {states['complete']} "
        f"complete, {states['pruned']} pruned, {states['fail']} failed (a trial cut short by a stop is one, its "
        f"gains queued again: {states['waiting']} waiting)",
        f"per trial (duration_s in trials.csv): mean {statistics.fmean(durations) if durations else float('nan'):.1f} "
        f"s, median {statistics.median(durations) if durations else float('nan'):.1f} s, max "
        f"{max(durations) if durations else float('nan'):.1f} s; complete trials mean "
        f"{statistics.fmean(complete) if complete else float('nan'):.1f} s; " +
        ("the trials are the study's, this command's wall is the trials it added and the report (the test runs)"
         if r.get("resumed") else f"outside the trials (baselines, test runs, start-up) {outside:.0f} s"),
        f"CPU {r['cpu_s']:.0f} s (the command and its workers: {r['cpu_s'] / r['wall_s']:.2f} cores on average); "
        f"peak RSS of one process {r['peak_rss_mb']:.0f} MB",
        f"load: 1-min load average {' '.join(r['load_before'])} before; during the run min {min(load):.2f}, mean "
        f"{statistics.fmean(load):.2f}, max {max(load):.2f} ({len(r['load'])} samples); other processes used "
        f"{r['others_cores']:.2f} cores on average",
        "gains,trial,split,decided,objective_m,median_advance_delta_m,traversal_ff,traversal_ctl,overloads_ff,"
        "overloads_ctl",
    ]
    for row in r["report"]:
        lines.append(",".join([row["gains"], row["trial"], row["split"], f"{row['decided']}/{row['conditions']}",
                               _f(row["objective"]), _f(row["median_advance_delta_m"]),
                               _f(row["feedforward_traversal"], ".2f"), _f(row["candidate_traversal"], ".2f"),
                               _f(row["feedforward_overloads"], ".1f"), _f(row["candidate_overloads"], ".1f")]))
    return lines


def _journal(folder: Path) -> dict[str, dict]:
    """A split's finished runs (``finished.jsonl``) by condition key."""
    from app.core.engines import RunJournal
    from app.core.tune import condition_key

    return {condition_key(row["scene"], float(row["tail_load_N"]), int(row["seed"])): row
            for row in RunJournal(folder).load().values()}


def _bootstrap(values: list[float], statistic: Callable[..., Any], resamples: int = 4000, seed: int = 0) -> tuple[float, float]:
    """The 95 % percentile interval of ``statistic`` over ``resamples`` resamples of the conditions."""
    import numpy as np

    if len(values) < 2:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    data = np.asarray(values)
    stats = [statistic(data[rng.integers(0, len(data), len(data))]) for _ in range(resamples)]
    low, high = np.percentile(stats, [2.5, 97.5])
    return float(low), float(high)


def per_condition(out: Path) -> tuple[list[dict], list[str]]:
    """Each condition's score (``app.core.tune.condition_score``) for the best and the base gains, train and test, from
    the study in ``out`` (the training runs as the study kept them, the test runs from ``out/test``), and the lines
    that summarise them: per gain set and split, the mean and the median score over the decided conditions, each with
    a 95 % bootstrap interval over conditions, and on the test conditions the best gains against the base gains on
    the conditions both decided."""
    import numpy as np
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)

    from app.core.tune import _rows_of_trial, condition_score, read_tune

    plan = read_tune(out / "tune.file.toml")
    report = _rows(out / "report.csv")
    study = optuna.load_study(study_name=None, storage=optuna.storages.JournalStorage(
        optuna.storages.journal.JournalFileBackend(str(out / "study.journal"))))
    best_gains = {row["gains"]: row["trial"] for row in report}
    baselines = {split: _journal(out / "baselines" / split) for split in ("train", "test")}
    # the test runs are in out/test/<label>-<gains hash>
    tests = {folder.name.split("-")[0]: _journal(folder) for folder in sorted((out / "test").iterdir())}
    rows: list[dict] = []
    for label, trial in best_gains.items():
        for split in ("train", "test"):
            runs = _rows_of_trial(study, int(trial)) if split == "train" and trial else tests.get(label, {})
            for key, ff in baselines[split].items():
                run = runs.get(key)
                if run is None:
                    continue
                value, why = condition_score(run, ff, plan.objective)
                rows.append({"gains": label, "trial": trial, "split": split, "condition": key,
                             "feedforward_outcome": ff.get("outcome"), "outcome": run.get("outcome"),
                             "feedforward_advance_at_rest_m": ff.get("advance_at_rest_m"),
                             "advance_at_rest_m": run.get("advance_at_rest_m"), "score_m": value,
                             "left_out": why})
    lines = ["gains,split,decided,mean_score_m,mean_95ci,median_score_m,median_95ci"]
    for label in best_gains:
        for split in ("train", "test"):
            values = [float(r["score_m"]) for r in rows if r["gains"] == label and r["split"] == split
                      and not r["left_out"]]
            total = sum(r["gains"] == label and r["split"] == split for r in rows)
            mean_ci = _bootstrap(values, np.mean)
            median_ci = _bootstrap(values, np.median)
            lines.append(f"{label},{split},{len(values)}/{total},{_f(str(np.mean(values)) if values else 'nan')},"
                         f"[{_f(str(mean_ci[0]))} {_f(str(mean_ci[1]))}],"
                         f"{_f(str(np.median(values)) if values else 'nan')},"
                         f"[{_f(str(median_ci[0]))} {_f(str(median_ci[1]))}]")
    if {"best", "base"} <= set(best_gains):
        score = {(r["gains"], r["condition"]): float(r["score_m"]) for r in rows
                 if r["split"] == "test" and not r["left_out"]}
        both = sorted({c for g, c in score if (("best", c) in score and ("base", c) in score)})
        differences = [score[("best", c)] - score[("base", c)] for c in both]
        ci = _bootstrap(differences, np.mean)
        lines.append(f"best - base on the test conditions both decided ({len(both)}): mean "
                     f"{_f(str(np.mean(differences)) if differences else 'nan')} m [{_f(str(ci[0]))} "
                     f"{_f(str(ci[1]))}]")
    return rows, lines


def run(quick: bool = False) -> None:
    """``sensnake bench``: quick, 3 trials into a temporary folder; otherwise the 40-trial study (long)."""
    with tempfile.TemporaryDirectory(prefix="sensnake_bench_tune_") as tmp:
        result = time_tune(PLAN, 3 if quick else 40, 2, Path(tmp) / "study")
        print("\n".join(summary(result)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plan", type=Path, default=PLAN)
    parser.add_argument("--trials", type=int, default=40)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "sensnake_bench_tune" / "study")
    parser.add_argument("--resume", action="store_true",
                        help="continue the study already in --out (a run cut short); timed on its own")
    parser.add_argument("--write", action="store_true", help=f"add the summary to {RESULTS.relative_to(ROOT)}")
    parser.add_argument("--conditions", type=Path, metavar="DIR",
                        help="no run: each condition's score in the finished study DIR, written to "
                             "DIR/per_condition.csv, and the scores' bootstrap intervals printed")
    args = parser.parse_args()
    if args.conditions is not None:
        rows, lines = per_condition(args.conditions.resolve())
        with open(args.conditions / "per_condition.csv", "w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        print("\n".join(lines))
        return
    result = time_tune(args.plan.resolve(), args.trials, args.jobs, args.out.resolve(), args.resume)
    lines = summary(result)
    if args.resume:
        lines[0] += " (resumed: the time is this command's alone)"
    print("\n".join(lines), flush=True)
    if args.write:
        with open(RESULTS, "a", encoding="utf-8") as f:
            f.write("\n".join(lines) + "\n")
    if result["exit"] != 0:
        print(f"bench_tune: the tuning exited {result['exit']}; see {result['log']}", file=sys.stderr)
        raise SystemExit(1)


if __name__ == "__main__":
    main()
