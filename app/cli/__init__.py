"""The command-line face: ``main`` parses the SPEC §1 arguments; one module per command (``run(args) -> int``),
imported only when that command runs. Commands call the Qt-free core (``app.core``) and print; nothing else."""

from app.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
