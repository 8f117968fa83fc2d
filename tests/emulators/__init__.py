"""Independent device emulators (SPEC §4 board, XM430 servo chain): separate processes on pseudo-terminals,
written from the datasheets and the SPEC, never from ``devices/``."""
