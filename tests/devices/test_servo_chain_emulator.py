"""The driver and the CLI robot commands against the independent XM430 emulator (``tests/emulators``): a separate
process on a pseudo-terminal, written from the Protocol 2.0 spec and the XM430-W350 e-manual, sharing no code with
``devices/`` or ``devices/sim``."""

from __future__ import annotations

import ast
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from devices.config import RobotConfig
from devices.servo_chain import ServoChain
from tests.emulators import xm430_emulator as emu_module
from tests.emulators.xm430_emulator import EmulatorProcess

pytestmark = pytest.mark.skipif(not sys.platform.startswith(("linux", "darwin")),
                                reason="the emulator needs os.openpty (Linux or macOS)")


@pytest.fixture
def emulator():
    process = EmulatorProcess()
    try:
        yield process
    finally:
        assert process.close() == 0


def robot_on(path: str, **changes) -> RobotConfig:
    return dataclasses.replace(RobotConfig(), port=path, **changes)


def test_the_emulator_shares_no_code_with_the_driver_or_the_simulator():
    tree = ast.parse(Path(emu_module.__file__).read_text(encoding="utf-8"))
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    imported |= {node.module or "" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert not {m for m in imported if m.split(".")[0] in ("devices", "app", "models", "widgets", "dynamixel_sdk")}


def test_the_emulator_packets_match_the_protocol_2_examples():
    # The e-manual's Protocol 2.0 examples: ping to ID 1 and the status packet of an XM430 (model 1030, fw 38).
    assert emu_module.packet(1, emu_module.INST_PING, b"") == bytes.fromhex("FFFFFD0001030001194E")
    assert emu_module.status_packet(1, 0, bytes.fromhex("060426")) == bytes.fromhex("FFFFFD00010700550006042665 5D")
    # Byte stuffing: FF FF FD inside the parameters gains an FD, and the parser takes it out again.
    stuffed = emu_module.packet(1, emu_module.INST_WRITE, bytes.fromhex("7400FFFFFD00"))
    assert bytes.fromhex("FFFFFDFD") in stuffed[7:]
    assert emu_module.Parser().feed(b"\x00garbage" + stuffed) == [(1, emu_module.INST_WRITE,
                                                                    bytes.fromhex("7400FFFFFD00"))]


def test_a_sync_read_pays_the_factory_return_delay_on_the_wire(emulator):
    with ServoChain(robot_on(emulator.path)) as chain:
        chain.read_state()
        t0 = time.perf_counter()
        for _ in range(5):
            chain.read_state()
        per_read_s = (time.perf_counter() - t0) / 5
    # 12 replies × (500 µs Return Delay Time + 21 bytes at 1 Mbps) plus the 26-byte instruction: ≥ 8.8 ms.
    assert per_read_s >= 12 * (500e-6 + 21e-5) + 26e-5


def test_scan_teach_and_play_commands_on_the_independent_chain(emulator, tmp_path, capsys):
    assert main(["scan", "--robot", emulator.path]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[1] for line in lines] == [str(i) for i in range(1, 13)]
    assert all("XM430-W350 (model 1020)" in line for line in lines)

    emulator.command("push 4 300")  # a person bends joint 4 by ~0.46 rad before the capture
    taught = tmp_path / "taught.json"
    assert main(["teach", "--robot", emulator.path, "--after", "0", "--out", str(taught)]) == 0
    angles = json.loads(taught.read_text())["angles_rad"]
    assert angles[3] == pytest.approx(300 * 2 * np.pi / 4096, abs=2e-3)
    assert emulator.state(4)["torque"] == 1  # teach ends holding the captured pose

    shape = json.loads(taught.read_text())
    shape["angles_rad"] = [0.2 * (-1) ** i for i in range(12)]
    played = tmp_path / "wave.json"
    played.write_text(json.dumps(shape))
    log = tmp_path / "play.csv"
    assert main(["play", str(played), "--robot", emulator.path, "--speed", "1", "--shifts", "1",
                 "--log", str(log)]) == 0
    assert "finished" in capsys.readouterr().out
    # The servos hold the last goal the log reports, and their present positions are what the log read back.
    rows = log.read_text().splitlines()
    assert len(rows) > 10
    last = [float(v) for v in rows[-1].split(",")]
    assert any(abs(a) > 0.1 for a in last[1:13])  # the wave moved the joints
    for k, sid in enumerate(range(1, 13)):
        state = emulator.state(sid)
        assert state["goal_writes"] > 0
        assert (state["goal"] - 2048) * 2 * np.pi / 4096 == pytest.approx(last[1 + k], abs=2e-3)
