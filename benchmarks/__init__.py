"""Benchmarks: each ``bench_*.py`` module exposes ``run(quick: bool) -> None`` that prints its tables.

``sensnake bench`` runs every one of them; ``python -m benchmarks.bench_<name> [--quick]`` runs one.
"""
