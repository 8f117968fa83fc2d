"""`sensnake experiment sweep`: the sweep file, runs in processes, summary.csv and the figure, the comparison."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

pytest.importorskip("mujoco")

from app.cli.main import main  # noqa: E402
from app.core.errors import SweepError
from app.core.sweep import compare, read_sweep, summary_svg, with_upsets


def test_a_tiny_sweep_writes_one_recording_per_run_a_summary_and_a_figure(tmp_path, capsys):
    plan = tmp_path / "sweep.toml"
    plan.write_text('scenes = ["paper_obstacle"]\ncontrollers = ["feedforward", "feedback"]\ntail_loads_n = [0.5]\n'
                    'seeds = [0, 1]\nseconds = 1.5\nsettle_s = 0.5\nspeed_rad_s = 0.2\n[[gains]]\npush_gain = 0.2\n',
                    encoding="utf-8")
    out = tmp_path / "out"
    assert main(["experiment", "sweep", str(plan), "--out", str(out), "--jobs", "2"]) == 0
    printed = capsys.readouterr().out
    assert "feedback g0 against feedforward over 2 paired runs" in printed
    # a short run's yardsticks are often undefined (no pair traversed): said in words, never a bare "nan"
    assert "nan" not in printed.lower().replace("nanny", ""), printed
    assert "median advance ratio " in printed and "time to traverse " in printed
    with open(out / "summary.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4  # 2 controllers × 2 seeds (one gain set)
    assert {r["controller"] for r in rows} == {"feedforward", "feedback"}
    assert all((out / r["file"]).exists() for r in rows)
    assert {r["tail_load_N"] for r in rows} == {"0.5"}
    assert all(r["crawled"] in ("0", "1") for r in rows)  # 1.5 s on the paper obstacle traverses nothing
    for r in rows:  # the draped body, 1.5 s into a play: its tail moved a little, its extent along x is a drape's
        assert abs(float(r["tail_advance_m"])) < 0.1
        assert 0.3 < float(r["end_extent_m"]) < 0.95  # shorter than the 0.96 m body: it lies over the cylinder
    keys = ("lost_ground_s", "rolled_s", "crawl_m", "crawled", "tail_advance_m", "end_extent_m")
    again = with_upsets([{k: v for k, v in r.items() if k not in keys} for r in rows], out)  # an older summary,
    # re-analysed from its recordings
    assert [float(a[k]) for a in again for k in keys] == pytest.approx([float(r[k]) for r in rows for k in keys],
                                                                       nan_ok=True)
    assert (out / "summary.svg").read_text(encoding="utf-8").startswith("<svg")
    # a second sweep into the same folder is refused: nothing a user does is overwritten
    assert main(["experiment", "sweep", str(plan), "--out", str(out)]) != 0
    assert "holds a sweep already" in capsys.readouterr().err


@pytest.mark.parametrize(("text", "words"), [
    ("scenes = []\n", "'scenes' must be a non-empty list"),
    ('scenes = ["flat"]\ncolour = 1\n', "unknown key 'colour'"),
    ('scenes = ["flat"]\ncontrollers = ["pid"]\n', "'controllers' must list"),
    ('scenes = ["flat"]\n[[gains]]\npush_gain = 9\n', "'push_gain' = 9 is outside"),
    ('scenes = ["flat"]\nseeds = [-1]\n', "'seeds' must be 0 or more"),
    # refused before any run (they used to run and fail one by one, or push the tail forward)
    ('scenes = ["flat"]\ntail_loads_n = [0.5, -1.0]\n', "'tail_loads_n' must be in"),
    ('scenes = ["flat"]\ntail_loads_n = [31]\n', "'tail_loads_n' must be in"),
    ('scenes = ["flat"]\nspeed_rad_s = 0\n', "'speed_rad_s' must be a number > 0"),
    ('scenes = ["flat"]\nseconds = 0\n', "'seconds' must be a number > 0"),
])
def test_a_bad_sweep_file_is_refused_naming_the_key(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SweepError, match=words.replace("(", r"\(")):
        read_sweep(path)


def test_the_comparison_pairs_runs_and_reads_the_issue_yardsticks():
    def row(controller, load, seed, traversed, advance, t=float("nan")):
        return {"scene": "s", "controller": controller, "gains_index": -1 if controller == "feedforward" else 0,
                "tail_load_N": load, "seed": seed, "traversed": traversed, "advance_m": advance,
                "overloads": 0, "traverse_s": t}

    rows = [row("feedforward", 0, 0, 1, 1.0, 20.0), row("feedback", 0, 0, 1, 1.1, 22.0),
            row("feedforward", 1, 0, 0, 0.4), row("feedback", 1, 0, 1, 0.8, 30.0),
            row("feedforward", 1, 1, 0, 0.2), row("feedback", 1, 1, 0, 0.3)]
    c = compare(rows)
    assert c.pairs == 3 and c.ff_fail_cases == 1
    assert (c.ff_success_in_those, c.fb_success_in_those) == (0.0, 0.5)
    assert c.median_advance_ratio == pytest.approx(1.5)  # ratios 1.1, 2.0, 1.5
    assert c.slower_where_ff_succeeds == pytest.approx(0.1)
    assert math.isnan(c.fb_crawled_in_those)  # a summary from before the upset columns: not known, not 0
    for r, crawl in zip(rows, (0.5, 0.6, 0.4, 0.05, 0.2, 0.3)):  # feedback's traversal where feedforward fails: a fall
        r["crawl_m"] = crawl
        r["crawled"] = int(bool(r["traversed"]) and crawl >= 0.2)
    assert math.isnan(c.median_tail_advance_ratio)  # no tail column: not known
    assert c.median_advance_ratio_both_traversed == pytest.approx(1.1)  # the one pair both traverse
    for r, tail in zip(rows, (0.9, 0.9, 0.2, 0.6, 0.1, 0.1)):
        r["tail_advance_m"] = tail
    c = compare(rows)
    assert c.median_tail_advance_ratio == pytest.approx(1.0)  # ratios 1.0, 3.0, 1.0
    assert c.median_advance_ratio == pytest.approx(1.5)  # unchanged: the yardstick is the centroid's
    assert (c.ff_crawled_in_those, c.fb_crawled_in_those) == (0.0, 0.0)
    assert c.fb_success_in_those == 0.5
    assert (c.ff_crawl_in_those, c.fb_crawl_in_those) == pytest.approx((0.3, 0.175))
    assert "traversed crawling" in summary_svg(rows)  # the figure draws the crawled rate once a summary has it
    assert "traversed crawling" not in summary_svg([{k: v for k, v in r.items() if k != "crawled"} for r in rows])


@pytest.mark.parametrize("path", sorted((Path(__file__).resolve().parents[2] / "benchmarks").glob("sweep_*.toml")),
                         ids=lambda p: p.name)
def test_every_sweep_file_in_the_benchmarks_reads_and_names_scenes_that_exist(path, monkeypatch):
    from devices.scene import load_scene

    monkeypatch.chdir(path.parents[1])  # scene paths in the files are relative to the repository
    plan = read_sweep(path)
    assert plan.scenes and plan.controllers
    for scene in plan.scenes:
        load_scene(scene)  # a built-in name or a file that parses
