"""Start an Xvfb server on a free display and run a probe subprocess on it with Qt's xcb platform.

Reusable outside this package (the calibration tests do): ``XServer.start()`` returns a running server or raises
:class:`XUnavailable` with the reason (no Xvfb binary, it failed to start); ``run_probe(display, scenario)`` runs
``python -m tests.realdisplay.probe <scenario>`` on that display and returns the JSON it printed. Any thread.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCREEN = "1600x1000x24"
START_TIMEOUT_S = 15.0
PROBE_TIMEOUT_S = 120.0


class XUnavailable(RuntimeError):
    """No X server can be started here (the message says why and how to get one)."""


@dataclass
class XServer:
    display: str
    process: subprocess.Popen

    @classmethod
    def start(cls, screen: str = SCREEN) -> XServer:
        """An Xvfb on the first free display (Xvfb picks it: ``-displayfd``), screen ``WxHxDepth``."""
        binary = shutil.which("Xvfb")
        if binary is None:
            raise XUnavailable("Xvfb is not installed (apt-get install xvfb; scripts/test.sh does it when root)")
        read_fd, write_fd = os.pipe()
        process = subprocess.Popen([binary, "-displayfd", str(write_fd), "-screen", "0", screen, "-nolisten", "tcp",
                                    "-noreset"], pass_fds=(write_fd,), stdout=subprocess.DEVNULL,
                                   stderr=subprocess.PIPE)
        os.close(write_fd)
        with os.fdopen(read_fd) as pipe:
            import select

            ready, _w, _x = select.select([pipe], [], [], START_TIMEOUT_S)
            number = pipe.readline().strip() if ready else ""
        if not number:
            process.kill()
            _out, err = process.communicate()
            raise XUnavailable(f"Xvfb did not start: {err.decode(errors='replace').strip()[-300:]}")
        return cls(f":{number}", process)

    def stop(self) -> None:
        self.process.terminate()
        try:
            self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        if self.process.stderr is not None:  # the pipe start() read a failure from: closed with the server (CI's
            self.process.stderr.close()  # last ResourceWarning, an unclosed BufferedReader GC'd in a later test)


def probe_env(display: str) -> dict[str, str]:
    """The environment of a probe: this checkout first on the path, the X display, Qt on xcb."""
    env = dict(os.environ)
    env.update(DISPLAY=display, QT_QPA_PLATFORM="xcb", PYQTGRAPH_QT_LIB="PySide6",
               PYTHONPATH=os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    env.pop("WAYLAND_DISPLAY", None)
    return env


def run_probe(display: str, scenario: str, *args: str, timeout_s: float = PROBE_TIMEOUT_S,
              module: str = "tests.realdisplay.probe") -> dict:
    """Run one probe scenario on ``display`` (of ``module``, a probe with the same command line); its JSON result
    (the last stdout line). AssertionError with the probe's output when it fails or prints no result."""
    command = [sys.executable, "-m", module, scenario, *args]
    done = subprocess.run(command, cwd=ROOT, env=probe_env(display), capture_output=True, text=True,
                          timeout=timeout_s)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode != 0 or not lines:
        raise AssertionError(f"probe {scenario!r} failed (exit {done.returncode}):\n{done.stdout[-2000:]}\n"
                             f"{done.stderr[-3000:]}")
    return json.loads(lines[-1])
