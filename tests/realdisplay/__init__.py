"""Live views checked on a real X display (Xvfb + Qt's xcb platform), pixels read back from the X server.

The offscreen platform and ``QWidget.grab()`` re-render a widget on request and so hide repaint bugs; these tests
run the app in a subprocess on an X server, count the paint events that reach each view and compare screen grabs
(``QScreen.grabWindow``). Helpers: :mod:`tests.realdisplay.xserver` (start Xvfb, run a probe on it) and
:mod:`tests.realdisplay.probe` (inside the subprocess: paint counter, screen grabs, one scenario per live view).
"""
