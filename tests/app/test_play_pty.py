"""`sensnake teach` and `sensnake play` end to end in subprocesses, over a real pseudo-terminal served by
`python -m devices.sim.pty_server` (the driver opens it as a serial port, exactly as it would a U2D2)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not sys.platform.startswith(("linux", "darwin")), reason="pseudo-terminals need Linux/macOS"),
]

REPO = Path(__file__).resolve().parents[2]
POSE_TICKS = [2048, 2100, 1990, 2048, 2150, 2048, 2000, 2048, 2048, 2080, 2048, 2048]
CMD_TIMEOUT_S = 60


@pytest.fixture
def pty_robot():
    server = subprocess.Popen([sys.executable, "-m", "devices.sim.pty_server", "--device", "robot", "--speed", "5"],
                              cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
    try:
        port = server.stdout.readline().strip()
        assert port.startswith("/dev/"), f"pty server did not print its port: {port!r}"

        def command(line: str) -> str:
            server.stdin.write(line + "\n")
            server.stdin.flush()
            return server.stdout.readline().strip()

        yield port, command
    finally:
        server.stdin.close()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
        server.stdout.close()


def sensnake(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-m", "app", *args], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=CMD_TIMEOUT_S)


def test_teach_then_play_over_a_pty(pty_robot, tmp_path):
    port, command = pty_robot
    for sid, ticks in enumerate(POSE_TICKS, start=1):
        assert command(f"limp {sid} {ticks}") == "ok"
    shape = tmp_path / "taught.json"
    done = sensnake("teach", "--robot", port, "--after", "0.2", "--out", str(shape))
    assert done.returncode == 0, done.stderr
    angles = np.asarray(json.loads(shape.read_text())["angles_rad"])
    np.testing.assert_array_equal(np.rint(angles / (2 * np.pi / 4096) + 2048).astype(int), POSE_TICKS)

    log = tmp_path / "log.csv"
    done = sensnake("play", str(shape), "--robot", port, "--speed", "0.5", "--shifts", "2", "--log", str(log))
    assert done.returncode == 0, done.stderr
    assert "finished" in done.stdout and "p99 error" in done.stdout
    rows = log.read_text().splitlines()
    assert rows[0].startswith("time_s,goal_rad_1") and len(rows) > 10


def test_play_overload_over_a_pty_exits_with_one_line(pty_robot, tmp_path):
    port, command = pty_robot
    shape = tmp_path / "bump.json"
    shape.write_text(json.dumps({"format": "sensnake-shape", "version": 1, "name": "bump",
                                 "axes": ["pitch", "yaw"] * 6, "angles_rad": [0.3] + [0.0] * 11}))
    env = dict(os.environ, PYTHONPATH=str(REPO))
    play = subprocess.Popen([sys.executable, "-m", "app", "play", str(shape), "--robot", port, "--speed", "0.1"],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = play.stdout.readline()  # "playing …" once the motion has been started
        assert first.startswith("playing"), first
        assert command("overload 3") == "ok"
        _out, err = play.communicate(timeout=CMD_TIMEOUT_S)
    finally:
        if play.poll() is None:
            play.kill()
            play.wait()
    assert play.returncode == 1
    assert err.strip().count("\n") == 0 and "servo 3 overload" in err
