"""One module per CLI command (``run(args) -> int``), imported only when that command runs."""
