"""The layering rules are checked by tools, not by discipline (STYLE.md): import-linter contracts, ruff, and
lazy loading of the heavy optional import (casadi)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=240)


@pytest.mark.skipif(shutil.which("lint-imports") is None, reason="import-linter not installed")
def test_import_contracts_hold():
    result = _run(["lint-imports", "--no-cache"])
    assert result.returncode == 0, result.stdout + result.stderr


def test_ruff_is_clean():
    result = _run([sys.executable, "-m", "ruff", "check", "app", "widgets", "devices", "models", "benchmarks", "tests"])
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.skipif(shutil.which("mypy") is None, reason="mypy not installed")
def test_type_checker_is_clean_on_models_and_devices():
    result = _run([sys.executable, "-m", "mypy"])  # files and options from [tool.mypy] in pyproject.toml
    assert result.returncode == 0, result.stdout + result.stderr


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
