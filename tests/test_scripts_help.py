"""Every script in scripts/ and tools/ answers --help with a usage line, and a bad argument with a usage line and
exit 2 (argparse's convention), never a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p for folder in ("scripts", "tools") for p in (ROOT / folder).iterdir()
                 if p.suffix in (".py", ".sh") and not p.name.startswith("_"))
PASS_THROUGH = {"run.sh", "test.sh"}  # other arguments go to the app / pytest


def _run(script: Path, *args: str) -> subprocess.CompletedProcess:
    command = [sys.executable, str(script), *args] if script.suffix == ".py" else ["bash", str(script), *args]
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=60)


def test_the_list_is_not_empty():
    assert {p.name for p in SCRIPTS} >= {"fault_matrix.py", "screenshot.py", "run.sh", "xcb_deps.sh"}


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_help_and_bad_arguments_give_a_usage_line(script):
    done = _run(script, "--help")
    assert done.returncode == 0, done.stderr[-1000:]
    assert done.stdout.lower().startswith("usage:"), done.stdout[:300]
    if script.name in PASS_THROUGH:
        return
    bad = _run(script, "--no-such-option")
    assert bad.returncode == 2, (bad.stdout[-500:], bad.stderr[-500:])
    assert "usage:" in bad.stderr.lower() and "Traceback" not in bad.stderr, bad.stderr[-1000:]


def test_the_sweep_figure_is_drawn_from_a_summary_and_never_clobbers_a_file(tmp_path):
    out = tmp_path / "figure.png"
    done = _run(ROOT / "scripts" / "sweep_figure.py", "benchmarks/results/feedback/feedback_heldout13_summary.csv", str(out))
    assert done.returncode == 0, done.stderr[-1000:]
    assert out.stat().st_size > 10_000 and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    before = out.read_bytes()
    again = _run(ROOT / "scripts" / "sweep_figure.py", "benchmarks/results/feedback/feedback_heldout13_summary.csv", str(out))
    assert again.returncode == 2 and "exists" in again.stderr and "Traceback" not in again.stderr
    assert out.read_bytes() == before
    empty = tmp_path / "empty.csv"
    empty.write_text("run,scene,controller\n", encoding="utf-8")
    refused = _run(ROOT / "scripts" / "sweep_figure.py", str(empty), str(tmp_path / "other.png"))
    assert refused.returncode == 2 and "no runs" in refused.stderr and not (tmp_path / "other.png").exists()
