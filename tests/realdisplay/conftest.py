"""One Xvfb for the whole session; every test here is skipped, with the reason, when none can be started."""

from __future__ import annotations

import pytest

from tests.realdisplay.xserver import XServer, XUnavailable


@pytest.fixture(scope="session")
def x_display():
    """The DISPLAY (``":N"``) of a private Xvfb, stopped at the end of the session."""
    try:
        server = XServer.start()
    except XUnavailable as exc:
        pytest.skip(f"real-display tests skipped: {exc}")
    yield server.display
    server.stop()
