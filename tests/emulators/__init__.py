"""Independent emulators of the lab's devices, each served on a pseudo-terminal by its own process and written from
the datasheets and SPEC, not from ``devices/`` or ``devices/sim`` (tests/test_architecture.py checks that)."""
