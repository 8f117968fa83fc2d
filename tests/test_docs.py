"""The README is a user's page (≤ 250 lines) and every link or picture in it and in docs/ resolves."""

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


def _screenshot_tool():
    """tools/screenshot.py (not a package): its sources_hash is what it records in the manifest."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("screenshot_tool", ROOT / "tools" / "screenshot.py")
    assert spec is not None and spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def test_every_readme_picture_of_a_tab_was_taken_from_the_code_as_it_is_now():
    """Each README picture of a tab was taken (tools/screenshot.py records the hash of the code it drew in
    docs/screenshots/manifest.json) from the code as it is now: a change to a tab's code makes its picture stale
    until it is retaken, even when the new picture is byte for byte the old one."""
    import json

    shots = ROOT / "docs" / "screenshots"
    sources = json.loads((shots / "sources.json").read_text(encoding="utf-8"))["pictures"]
    manifest = json.loads((shots / "manifest.json").read_text(encoding="utf-8"))
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    shown = set(re.findall(r"docs/screenshots/([\w.-]+\.png)", readme))
    assert set(sources) <= shown, f"pictures mapped but not in the README: {set(sources) - shown}"
    sources_hash = _screenshot_tool().sources_hash
    stale = [picture for picture, files in sources.items() if manifest.get(picture) != sources_hash(files)]
    assert not stale, (f"README pictures older than their tab's code: {stale}; retake them on an X display "
                       "(python tools/screenshot.py --xvfb; see its --help for the 3-D and feedback ones)")


def test_a_changed_source_changes_the_hash_the_freshness_check_compares(tmp_path, monkeypatch):
    tool = _screenshot_tool()
    (tmp_path / "a.py").write_text("x = 1\n")
    monkeypatch.setattr(tool, "ROOT", tmp_path)
    before = tool.sources_hash(["a.py"])
    (tmp_path / "a.py").write_text("x = 2\n")
    assert tool.sources_hash(["a.py"]) != before


def test_the_docs_name_the_fit_solver_the_code_defaults_to():
    from models.calibration import DEFAULT_SOLVER

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert DEFAULT_SOLVER == "scipy" and "scipy `least_squares` by default" in readme
    assert "CasADi Gauss–Newton by default" not in readme
