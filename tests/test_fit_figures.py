"""The fit's promised figures are the benchmarks' measured ones: docs/NUMERICS.md's coverage table is the one
``python -m benchmarks.bench_coverage --from-csv benchmarks/results/coverage.csv`` prints, the results file is what
today's fitter gives (one sensor refitted from its seed), and the `sensnake fit` speed figures in docs/NUMERICS.md
and docs/BENCHMARKS.md are rows of ``benchmarks/results/fit_cli.txt`` (``python -m benchmarks.bench_fit_cli``; the
ceiling sensor's of ``fit_cli_ceiling.txt``, ``--sensor ceiling``)."""

from __future__ import annotations

from pathlib import Path

from benchmarks import bench_coverage, bench_fit_cli

ROOT = Path(__file__).resolve().parents[1]
NUMERICS = ROOT / "docs" / "NUMERICS.md"
BENCHMARKS = ROOT / "docs" / "BENCHMARKS.md"
FIT_CLI = ROOT / "benchmarks" / "results" / "fit_cli.txt"
FIT_CLI_CEILING = ROOT / "benchmarks" / "results" / "fit_cli_ceiling.txt"  # --sensor ceiling


def test_the_coverage_table_in_numerics_is_the_benchmarks_own() -> None:
    runs = bench_coverage.read_records(bench_coverage.RESULTS_CSV)
    assert all(len(rows) * 12 >= 200 for rows in runs.values()), "fewer than 200 trials in a row"
    page = NUMERICS.read_text(encoding="utf-8")
    missing = [line for line in bench_coverage.docs_table(runs) if line not in page]
    assert not missing, f"docs/NUMERICS.md lacks these lines of the benchmark's table: {missing}"


def test_the_results_file_is_what_todays_fitter_gives() -> None:
    """The first sensor of the first run in the results file, refitted from its seed (~3 s): the same hits."""
    header, first = bench_coverage.RESULTS_CSV.read_text().splitlines()[:2]
    assert header.startswith("pipeline,trend,rate_hz,noise_rel,seed,sensor,")
    pipeline, trend, rate, noise, seed, index = first.split(",")[:6]
    sensor_seed = bench_coverage.sensor_seeds(int(seed), int(index) + 1)[int(index)]
    hits, info = bench_coverage.sensor_record(sensor_seed, float(noise), bool(int(trend)), float(rate), pipeline)
    recorded = dict(cell.split("=") for cell in first.split(",", 9)[9].split(";"))
    assert {key: f"{sum(v)}/{len(v)}" for key, v in hits.items()} == recorded
    assert float(first.split(",")[6]) == info["ceiling"]


def test_the_fit_speed_figures_in_the_docs_are_the_benchmarks_measured_ones() -> None:
    """Each sentence ``bench_fit_cli.summaries`` makes of the saved output (CPU, wall, peak memory, worst parameter
    error per configuration) is quoted in docs/NUMERICS.md, and the default's in docs/BENCHMARKS.md."""
    sentences = bench_fit_cli.summaries(FIT_CLI.read_text(encoding="utf-8"))
    assert any("default" in s for s in sentences), "no default row in benchmarks/results/fit_cli.txt"
    numerics = NUMERICS.read_text(encoding="utf-8")
    assert [s for s in sentences if s not in numerics] == [], "docs/NUMERICS.md does not quote these"
    ceiling = bench_fit_cli.summaries(FIT_CLI_CEILING.read_text(encoding="utf-8"))
    assert ceiling and all("ceiling sensor" in s for s in ceiling)
    assert [s for s in ceiling if s not in numerics] == [], "docs/NUMERICS.md does not quote the ceiling sensor's"
    benchmarks = BENCHMARKS.read_text(encoding="utf-8")
    assert [s for s in sentences if "default" in s and s not in benchmarks] == []
