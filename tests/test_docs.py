"""The README is a user's page (≤ 250 lines) and every link or picture in it and in docs/ resolves (issue 27)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def test_the_readme_is_short():
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) <= 250


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_relative_link_and_picture_resolves(page):
    text = page.read_text(encoding="utf-8")
    missing = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z]+://", target) or target.startswith("mailto:"):
            continue
        if target.startswith("../shared/"):  # the contracts, beside the repository (not part of it)
            continue
        if not (page.parent / target).resolve().exists():
            missing.append(target)
    assert not missing, f"{page.name}: links that do not resolve: {missing}"


def test_every_command_in_the_readme_is_one_the_parser_knows():
    from app.cli.main import build_parser

    known = set(build_parser()._subparsers._group_actions[0].choices)  # noqa: SLF001 - argparse keeps them here
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    used = set(re.findall(r"`sensnake (\w+)", text))
    assert used and used <= known, f"the README names commands the CLI does not have: {used - known}"


def test_the_config_page_is_what_the_code_says():
    import subprocess
    import sys

    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "config_doc.py"), "--check"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_every_environment_switch_the_code_reads_is_in_the_config_page():
    names: set[str] = set()
    for folder in ("app", "devices", "models", "widgets", "scripts", "tools", "benchmarks"):
        for path in (ROOT / folder).rglob("*.py"):
            names |= set(re.findall(r"SENSNAKE_[A-Z_]+", path.read_text(encoding="utf-8")))
    for path in (ROOT / "scripts").glob("*.sh"):
        names |= set(re.findall(r"SENSNAKE_[A-Z_]+", path.read_text(encoding="utf-8")))
    documented = set(re.findall(r"`(SENSNAKE_[A-Z_]+)`", (ROOT / "docs" / "CONFIG.md").read_text(encoding="utf-8")))
    assert names <= documented, f"switches the code reads that docs/CONFIG.md does not explain: {names - documented}"


# Each README picture and the code that draws what it shows: a change to that code after the picture was taken makes
# the picture stale. Retake them all with `python tools/screenshot.py --xvfb` (and --physics/--scene/--feedback for the
# 3-D and feedback ones: tools/screenshot.py --help).
PICTURE_SOURCES = {
    "teach.png": ["app/gui/tabs/teach.py", "widgets/teach_panel.py", "widgets/joint_sliders.py",
                  "widgets/body_view.py"],
    "gait.png": ["app/gui/tabs/gait.py", "widgets/gait_panel.py", "widgets/body_view.py"],
    "gait-feedback.png": ["app/gui/tabs/gait.py", "widgets/gait_panel.py", "widgets/body_view.py"],
    "calibration.png": ["app/gui/tabs/calibration.py", "widgets/calibration_run.py", "widgets/sensor_picker.py"],
    "forces.png": ["app/gui/tabs/forces.py", "widgets/force_plots.py", "widgets/forces_panel.py",
                   "widgets/body_view.py"],
    "hardware.png": ["app/gui/tabs/hardware.py", "widgets/hardware_panel.py"],
    "scene.png": ["app/gui/tabs/scene.py", "widgets/scene_view.py"],
}


def _last_commit_time(*paths: str) -> int | None:
    import subprocess

    done = subprocess.run(["git", "log", "-1", "--format=%ct", "--", *paths], cwd=ROOT, capture_output=True,
                          text=True, timeout=30)
    return int(done.stdout.strip()) if done.returncode == 0 and done.stdout.strip() else None


def test_every_readme_picture_of_a_tab_is_newer_than_the_code_that_draws_it():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    shown = set(re.findall(r"docs/screenshots/([\w.-]+\.png)", readme))
    assert set(PICTURE_SOURCES) <= shown, f"pictures mapped here but not in the README: {set(PICTURE_SOURCES) - shown}"
    if _last_commit_time("README.md") is None:
        pytest.skip("not a git checkout with history: the pictures' age cannot be read")
    stale = []
    for picture, sources in PICTURE_SOURCES.items():
        taken = _last_commit_time(f"docs/screenshots/{picture}")
        changed = _last_commit_time(*sources)
        if taken is not None and changed is not None and taken < changed:
            stale.append(picture)
    assert not stale, (f"README pictures older than their tab's code: {stale}; retake them on an X display "
                       "(python tools/screenshot.py --xvfb; see its --help for the 3-D and feedback ones)")


def test_the_docs_name_the_fit_solver_the_code_defaults_to():
    from models.calibration import DEFAULT_SOLVER

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert DEFAULT_SOLVER == "scipy" and "scipy `least_squares` by default" in readme
    assert "CasADi Gauss–Newton by default" not in readme
