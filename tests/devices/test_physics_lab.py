"""The physics world under the virtual hardware: the real drivers talk to a chain and a board backed by MuJoCo.

Clocks run 4× real time (the physics keeps up with that on a loaded 2-core machine); every wait is on a condition.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("devices.sim.physics.world")  # the package sets MUJOCO_GL before mujoco loads

from devices import control_table as ct  # noqa: E402
from devices.board import BoardReader  # noqa: E402
from devices.config import LabConfig, SimLabConfig  # noqa: E402
from devices.errors import ServoHardwareError  # noqa: E402
from devices.servo_chain import ServoChain  # noqa: E402
from devices.sim.clock import SimClock  # noqa: E402
from devices.sim.dxl_chain import ChainLab, VirtualChain  # noqa: E402
from devices.sim.physics.backend import PhysicsBackend  # noqa: E402
from devices.sim.physics.model import SceneParams  # noqa: E402

FLAT = dataclasses.replace(LabConfig(), lab=SimLabConfig(physics="mujoco", obstacle_height_ratio=0.0))
STALL_CURRENT_MA = 4.1 / (4.1 / 2.3) * 1000.0


def test_the_default_config_gives_the_physics_lab():
    """With mujoco importable (this module skips otherwise), the packaged config's simulated lab is the physics lab;
    tests/app/test_scene_tab.py checks the scripted fallback, and its reason, without it."""
    from devices.config import load_config
    from devices.sim.lab import SimLab

    lab = SimLab(load_config())
    try:
        assert isinstance(lab.physics, PhysicsBackend) and lab.physics_note == ""
        assert lab.chain.present_positions_rad().shape == (12,)  # the chain reads the world
    finally:
        lab.close()


def _frames(reader: BoardReader, n: int):
    assert reader.wait_for_frames(n, timeout_s=30.0), "the board sent no frames"
    block = reader.read_block()
    assert block is not None
    return block


def test_drivers_move_the_simulated_body_and_the_board_feels_it(install_fast_sim_lab):
    lab = install_fast_sim_lab(FLAT, speed=4.0)
    assert lab.physics is not None
    names = lab.config.board.channel_names
    tail, middle = names.index("S12B"), names.index("S06B")
    with ServoChain(lab.config.robot) as chain, BoardReader(lab.config.board) as reader:
        chain.set_torque(True)
        resting = _frames(reader, 10).conductance_s[-1]
        assert resting[tail] > 0 and resting[middle] > 0  # every segment rests on the ground
        goal = np.zeros(12)
        goal[10] = 0.5  # joint 11 (pitch) lifts segments 11 and 12
        chain.write_goals(goal)
        for _ in range(1000):  # until it holds there (the board's thread keeps stepping the world meanwhile)
            state = chain.read_state()
            if abs(state.position_rad[10] - 0.5) < 0.03 and np.abs(state.velocity_rad_s).max() < 0.05:
                break
        assert state.position_rad[10] == pytest.approx(0.5, abs=0.03)
        # The driver reads what the physics says (to the encoder's noise), and a held joint draws current.
        assert lab.physics.joint_state().position_rad[10] == pytest.approx(state.position_rad[10], abs=0.01)
        assert abs(state.current_ma[10]) > 20.0
        _frames(reader, 1)
        lifted = _frames(reader, 5).conductance_s[-1]
    assert lifted[tail] < 0.02 * resting[tail]  # no force: the sensor reads open (to the ADC noise)
    assert lifted[middle] > 0.0


def test_a_joint_stalled_by_a_load_it_cannot_move_draws_current_then_trips_overload(install_sim_device):
    clock = SimClock(4.0)
    backend = PhysicsBackend(FLAT, clock, scene=SceneParams(obstacle_height_m=0.0))
    robot = FLAT.robot
    chain_sim = VirtualChain(robot.joint_ids, robot.baud, clock, seed=3, physics=backend)
    install_sim_device("robot", ChainLab(chain_sim).chain)
    goal = np.zeros(12)
    backend.set_external_torque(11, -6.0)  # a push on joint 12 stronger than its servo's 4.1 N·m stall
    currents = []
    with ServoChain(robot) as chain:
        chain.set_torque(True)
        chain.write_goals(goal)
        with pytest.raises(ServoHardwareError) as tripped:
            for _ in range(2000):
                currents.append(abs(chain.read_state().current_ma[11]))
    assert tripped.value.servo_id == 12
    assert "overload" in str(tripped.value).lower()
    assert max(currents) > 0.85 * STALL_CURRENT_MA  # rising toward the limit before the trip
    assert chain_sim.register(12, "Hardware Error Status") & (1 << ct.OVERLOAD_BIT)
    assert chain_sim.register(12, "Torque Enable") == 0  # the firmware let go


def test_the_process_wide_physics_lab_stops_its_thread_before_the_interpreter_exits():
    """`sensnake record --daq sim` that failed at once crashed with SIGSEGV (2 of 15 runs) after its error message:
    the physics lab's daemon thread was still stepping MuJoCo while Python shut down. The lab made on first use of
    a `sim` port now stops that thread at exit; a handler registered before it runs after it and looks."""
    import subprocess
    import sys
    from pathlib import Path

    script = (
        "import atexit, threading\n"
        "def look():\n"
        "    alive = any(t.name == 'physics-lab' and t.is_alive() for t in threading.enumerate())\n"
        "    print('alive at exit' if alive else 'stopped at exit', flush=True)\n"
        "atexit.register(look)\n"
        "from devices import factory\n"
        "factory.sim_lab()\n"
        "print('running' if any(t.name == 'physics-lab' for t in threading.enumerate()) else 'no thread')\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                          cwd=Path(__file__).resolve().parents[2])
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n")[:2] == ["running", "stopped at exit"], done.stdout


def test_a_board_frame_read_late_carries_the_forces_of_its_own_instant():
    """The board samples at k / 30 s; a host reading it on a 50 Hz tick asks for frames already stepped past. Those
    read what the sheets carried at the frame's instant (kept on the way), not the forces of whenever the host came —
    the latter put a 0-20 ms error cycling with the 50/30 Hz beat into every frame of a moving body."""
    from devices.sim.physics.headless import ManualClock

    def dropping(clock: ManualClock) -> PhysicsBackend:
        backend = PhysicsBackend(FLAT, clock, scene=SceneParams(obstacle_height_m=0.0))  # type: ignore[arg-type]
        backend.world.place(height_m=0.12)  # 8 cm above the floor: it falls, lands and rebounds — loads change fast
        return backend

    period = 1.0 / FLAT.board.rate_hz
    late_clock, on_time_clock = ManualClock(), ManualClock()
    late, on_time = dropping(late_clock), dropping(on_time_clock)
    late_clock.set(0.5)
    late.advance_to(0.5)  # the host comes late: every frame up to 0.5 s is read now
    changed = 0
    for k in range(1, 15):
        on_time_clock.set(k * period)
        on_time.advance_to(k * period)
        truth = on_time.world.segment_loads_n()  # read at the instant, from a world stepped the same way
        expected = np.zeros(len(FLAT.board.channel_names))
        expected[late._known] = truth[late._rows[late._known], late._segments[late._known]]
        assert late.forces_n(k * period) == pytest.approx(expected, abs=1e-9)
        changed += not np.allclose(expected, late.forces_n(0.5), atol=0.05)
    assert changed >= 7  # the body was moving: the present forces would have been wrong
