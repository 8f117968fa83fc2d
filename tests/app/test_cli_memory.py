"""The command line under memory limits: one BLAS thread per process, and running out of memory (or of address
space for a library) is one line naming the limit; SENSNAKE_DEBUG=1 keeps the traceback."""

from __future__ import annotations

import importlib

import pytest

cli = importlib.import_module("app.cli.main")  # the module (``app.cli.main`` is also the name of its function)


def test_numeric_thread_pools_are_bounded_unless_the_user_set_them(monkeypatch):
    for name in cli.NUMERIC_THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    cli.bound_numeric_threads()
    import os

    assert os.environ["OMP_NUM_THREADS"] == "3"  # the user's
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1" and os.environ["MKL_NUM_THREADS"] == "1"


def test_a_memory_error_is_one_line_naming_the_address_space_limit(monkeypatch, capsys):
    def out_of_memory(_args: object) -> int:
        raise MemoryError

    monkeypatch.setattr("app.cli.bench.run", out_of_memory)
    monkeypatch.setattr(cli, "address_space_limit", lambda: 300 << 20)
    assert cli.main(["bench", "--quick"]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == ["sensnake bench: error: out of memory: this process may use only 300 MB of address space "
                     "(ulimit -v 307200), less than the numerical libraries need to load and run (about 2 GB for "
                     "fit): raise the limit (ulimit -v unlimited)"]


def test_a_library_that_cannot_be_mapped_under_the_limit_is_memory_and_a_missing_module_a_traceback(monkeypatch,
                                                                                                      capsys):
    def unmappable(_args: object) -> int:
        raise ImportError("_flapack.so: failed to map segment from shared object")

    monkeypatch.setattr("app.cli.bench.run", unmappable)
    monkeypatch.setattr(cli, "address_space_limit", lambda: 300 << 20)
    assert cli.main(["bench"]) == 1
    assert "out of memory" in capsys.readouterr().err
    monkeypatch.setenv("SENSNAKE_DEBUG", "1")
    with pytest.raises(ImportError):
        cli.main(["bench"])
    monkeypatch.delenv("SENSNAKE_DEBUG")

    def missing(_args: object) -> int:
        raise ModuleNotFoundError("No module named 'nothing_here'")

    monkeypatch.setattr("app.cli.bench.run", missing)
    with pytest.raises(ModuleNotFoundError):  # a broken install is shown as it is
        cli.main(["bench"])
