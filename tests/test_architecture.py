"""The layering rules are checked by tools, not by discipline (STYLE.md): import-linter contracts, ruff, mypy on
every package, no import circles, and lazy loading of the heavy optional import (casadi)."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=240)


# scripts/test.sh runs ruff, mypy and the import contracts on the same tree just before the tests and stops if any
# fails; it says so in this variable, and the tests below do not run them a second time.
checked_by_test_script = pytest.mark.skipif(os.environ.get("SENSNAKE_STATIC_CHECKS_PASSED") == "1",
                                            reason="scripts/test.sh ran this check before the tests")


@checked_by_test_script
@pytest.mark.skipif(shutil.which("lint-imports") is None, reason="import-linter not installed")
def test_import_contracts_hold():
    result = _run(["lint-imports", "--no-cache"])
    assert result.returncode == 0, result.stdout + result.stderr


@checked_by_test_script
def test_ruff_is_clean():
    result = _run([sys.executable, "-m", "ruff", "check", "app", "widgets", "devices", "models", "benchmarks", "tests"])
    assert result.returncode == 0, result.stdout + result.stderr


@checked_by_test_script
@pytest.mark.skipif(shutil.which("mypy") is None, reason="mypy not installed")
def test_type_checker_is_clean_on_every_package():
    result = _run([sys.executable, "-m", "mypy"])  # files and options from [tool.mypy] in pyproject.toml
    assert result.returncode == 0, result.stdout + result.stderr


# The modules mypy still excepts (pyproject's [[tool.mypy.overrides]] ignore_errors). This number only goes down:
# fix a module's errors and take it off the list, never add one (napari's rule).
MAX_MYPY_EXCEPTED_MODULES = 0  # every module is checked; keep it so
# The modules still excepted from disallow_untyped_defs / check_untyped_defs: this number only goes down.
MAX_MYPY_UNTYPED_MODULES = 28


def test_checks_cover_every_package_and_their_exceptions_only_shrink():
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]
    assert {"app", "widgets", "devices", "models", "benchmarks"} <= set(config["mypy"]["files"])
    excepted = [module for override in config["mypy"].get("overrides", []) if override.get("ignore_errors")
                for module in override["module"]]
    assert len(excepted) <= MAX_MYPY_EXCEPTED_MODULES, f"mypy exceptions grew: {excepted}"
    assert config["mypy"]["disallow_untyped_defs"] and config["mypy"]["check_untyped_defs"]
    untyped = [module for override in config["mypy"].get("overrides", [])
               if override.get("disallow_untyped_defs") is False for module in override["module"]]
    assert len(untyped) <= MAX_MYPY_UNTYPED_MODULES, f"modules excepted from typed defs grew: {len(untyped)}"
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert f"{len(untyped)} modules" in readme, "README no longer says how many modules are still untyped"
    loose = [c["name"] for c in config["importlinter"]["contracts"] if c.get("allow_indirect_imports")]
    assert not loose, f"contracts that allow indirect imports (name the one way through with ignore_imports): {loose}"
    test_script = (ROOT / "scripts" / "test.sh").read_text(encoding="utf-8")
    for check in ("ruff check", "mypy", "lint_imports", "pytest"):
        assert check in test_script, f"scripts/test.sh (what .ci/run runs) no longer runs {check}"


def test_casadi_loads_only_when_first_needed():
    code = (
        "import sys, importlib, pkgutil\n"
        "import models, app.cli\n"
        "for m in pkgutil.iter_modules(models.__path__):\n"
        "    importlib.import_module('models.' + m.name)\n"
        "assert 'casadi' not in sys.modules, 'importing models pulled in casadi'\n"
        "assert 'PySide6' not in sys.modules, 'importing models pulled in Qt'\n"
    )
    result = _run([sys.executable, "-c", code])
    assert result.returncode == 0, result.stderr


@pytest.mark.skipif(importlib.util.find_spec("grimp") is None, reason="grimp (import-linter's graph) not installed")
def test_no_import_circles_between_our_modules():
    """Any two of our modules importing each other, directly or round a longer loop (function-level imports count),
    is a circle: list every strongly connected component of the module graph with more than one member."""
    import grimp

    graph = grimp.build_graph("app", "widgets", "devices", "models", "benchmarks", cache_dir=None)
    circles = [sorted(component) for component in _strongly_connected(graph) if len(component) > 1]
    assert not circles, f"import circles: {circles}"


def _strongly_connected(graph) -> list[list[str]]:
    """Tarjan's algorithm, iterative (the graph has a few hundred modules)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []
    for root in sorted(graph.modules):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.find_modules_directly_imported_by(root))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, successors = work[-1]
            advanced = False
            for succ in successors:
                if succ not in index:
                    index[succ] = low[succ] = len(index)
                    stack.append(succ)
                    on_stack.add(succ)
                    work.append((succ, iter(sorted(graph.find_modules_directly_imported_by(succ)))))
                    advanced = True
                    break
                if succ in on_stack:
                    low[node] = min(low[node], index[succ])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                components.append(component)
    return components


def test_tests_sleep_only_where_a_comment_says_time_must_pass_on_purpose():
    """Tests wait on conditions (tests/waiting.py); a sleep is only there when the passing of time is the test, and
    the line above says so ("Deliberate")."""
    offenders = []
    for path in sorted((ROOT / "tests").rglob("*.py")):
        if "emulators" in path.parts:  # the emulators are devices keeping their own pace, not tests
            continue
        lines = path.read_text(encoding="utf-8").splitlines()
        for number, line in enumerate(lines):
            if "time.sleep(" in line and "real_sleep" not in line and "Deliberate" not in lines[number - 1]:
                offenders.append(f"{path.relative_to(ROOT)}:{number + 1}")
    assert not offenders, f"sleeps in tests without a 'Deliberate' comment above: {offenders}"


def test_error_classes_live_in_their_packages_errors_module():
    """A newcomer finds every error a package raises in one file (``devices/errors.py``, ``app/core/errors.py``,
    ``models/errors.py``): an exception class defined anywhere else in those packages fails here, named."""
    import ast

    homes = {"devices": ROOT / "devices" / "errors.py", "app": ROOT / "app" / "core" / "errors.py",
             "models": ROOT / "models" / "errors.py", "widgets": None}
    misplaced, found = [], {}
    for package, home in homes.items():
        for path in sorted((ROOT / package).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in tree.body:
                if not isinstance(node, ast.ClassDef) or node.name.startswith("_"):
                    continue  # a private exception is a module's own control flow, never raised to a caller
                bases = {b.id if isinstance(b, ast.Name) else getattr(b, "attr", "") for b in node.bases}
                if not any(base.endswith(("Error", "Exception", "Unavailable")) for base in bases):
                    continue
                if path == home:
                    found.setdefault(package, []).append(node.name)
                elif "sim" not in path.parts and "emulators" not in path.parts:
                    misplaced.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}")
    assert not misplaced, f"error classes outside their package's errors module: {misplaced}"
    # The homes hold them (the check above would pass vacuously if the walk found nothing).
    assert {"DeviceError", "ServoLostError", "ConfigError", "ProtocolError"} <= set(found["devices"])
    assert {"CalFileError", "RecordingError", "SettingsError"} <= set(found["app"])
    assert {"TrajectoryError", "GainsError"} <= set(found["models"])
