"""Teach logic shared by ``sensnake teach`` and the Teach tab (no Qt).

Posing by hand: torque off (all joints or a selection), read the joint angles while a person bends the robot,
capture the pose (rad, SPEC §2 convention), then turn torque back on *holding* the captured pose without a jump:
the goal registers are first written with the present positions, then torque is enabled, so the servos start out
already at their goal.

Every bus operation is a named command (:class:`devices.bus_commands.BusCommand`: a module-level function and its
arguments, so it can also run in the control loop's own process) run on the thread that owns the port, through a
``run_on_bus(command) -> Future`` callable: ``RobotController.submit`` (CLI) or ``RobotBridge.run_on_bus`` (GUI).
Methods here return those futures and may be called from any thread; the commands run on the bus thread.

In the simulated lab there is no hand to bend the robot, so :class:`SimHand` poses limp joints of the simulated
chain directly (``VirtualChain.set_limp_position``); :func:`sim_hand_for` returns one only for a ``sim`` port. In
the physics lab the hand keeps holding what it bent until torque goes on or it lets go (:meth:`SimHand.let_go`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from devices import bus_commands
from devices.bus_commands import bus_command
from devices.config import RobotConfig
from devices.control_table import CENTER_TICKS, RAD_PER_TICK
from devices.errors import JointLimitError
from devices.factory import is_sim

T = TypeVar("T")
RunOnBus = Callable[[Callable[[Any], T]], "Future[T]"]

LIMIT_TOLERANCE_RAD = RAD_PER_TICK  # one tick of slack: a joint resting on its limit may be held there


@dataclass(frozen=True)
class CapturedPose:
    """A captured pose: ``angles_rad`` (n,) in joint order, read at ``host_time_s`` (``time.monotonic()``)."""

    angles_rad: np.ndarray
    host_time_s: float


def _read_pose(chain: Any) -> CapturedPose:
    state = chain.read_state()
    return CapturedPose(np.array(state.position_rad, dtype=float), float(state.host_time_s))


def _goals_to_present(chain: Any, robot: RobotConfig) -> np.ndarray:
    """Bus thread: goals := present positions (one sync write). Returns the goals sent (rad)."""
    state = chain.read_state()
    present = np.array(state.position_rad, dtype=float)
    lo, hi = np.asarray(robot.joint_min_rad), np.asarray(robot.joint_max_rad)
    outside = np.flatnonzero((present < lo - LIMIT_TOLERANCE_RAD) | (present > hi + LIMIT_TOLERANCE_RAD))
    if outside.size:
        j = int(outside[0])
        # write_goals would clamp this joint and the servo would jump to its limit when torque comes on
        raise JointLimitError(
            f"joint {robot.joint_ids[j]} is at {present[j]:.3f} rad, outside its limits "
            f"[{lo[j]:.2f}, {hi[j]:.2f}] rad: bend it back inside by hand before turning torque on")
    return np.asarray(chain.write_goals(present), dtype=float)


class TeachSession:
    """Torque off / capture / hold for one robot, over ``run_on_bus``. Any thread may call; returns futures."""

    def __init__(self, run_on_bus: RunOnBus, robot: RobotConfig,
                 set_torque: Callable[[bool, list[int] | None], Future] | None = None) -> None:
        """``set_torque(enabled, ids) -> Future`` defaults to ``chain.set_torque`` on the bus; pass
        ``RobotController.set_torque`` so the controller also forgets its last goal (its speed limit then starts
        from where the hand left the joints)."""
        self._run = run_on_bus
        self.robot = robot
        self._set_torque = set_torque or (
            lambda enabled, ids: run_on_bus(bus_command(bus_commands.set_torque, enabled, ids)))

    def torque_off(self, ids: Sequence[int] | None = None) -> Future:
        """Let the selected joints (servo IDs; default all) go limp so they can be posed by hand."""
        chosen = None if ids is None else [int(i) for i in ids]
        self._check_ids(chosen)
        return self._set_torque(False, chosen)

    def capture(self) -> Future:
        """Read the present pose (one sync read); the future's result is a :class:`CapturedPose`."""
        return self._run(bus_command(_read_pose))

    def hold(self, ids: Sequence[int] | None = None) -> Future:
        """Torque on for ``ids`` (default all) holding where the joints are now; result: the goals sent (rad).

        Refuses (``JointLimitError``) if a joint rests outside its configured limits, rather than let it jump.
        """
        chosen = None if ids is None else [int(i) for i in ids]
        self._check_ids(chosen)
        robot = self.robot
        result: Future = Future()
        goals_written = self._run(bus_command(_goals_to_present, robot))

        def then_torque_on(done: Future) -> None:
            # Only once the goals equal the present positions may torque come on (else the servos jump).
            if done.cancelled():
                result.cancel()
                return
            if done.exception() is not None:
                result.set_exception(done.exception())
                return
            goals = done.result()
            try:
                torque = self._set_torque(True, chosen)
            except (OSError, RuntimeError, ValueError) as exc:  # e.g. disconnected meanwhile
                result.set_exception(exc)
                return
            torque.add_done_callback(lambda t: _settle(result, t, goals))

        goals_written.add_done_callback(then_torque_on)
        return result

    def _check_ids(self, ids: Sequence[int] | None) -> None:
        if ids is None:
            return
        unknown = [i for i in ids if i not in self.robot.joint_ids]
        if unknown:
            raise ValueError(f"servo {unknown[0]} is not one of the robot's joints {list(self.robot.joint_ids)}")


def _settle(result: Future, done: Future, value: Any) -> None:
    if done.cancelled():
        result.cancel()
    elif done.exception() is not None:
        result.set_exception(done.exception())
    else:
        result.set_result(value)


def ticks_from_angle(robot: RobotConfig, joint_index: int, angle_rad: float) -> float:
    """Position ticks (float) for a joint angle, the inverse of SPEC §2 with the joint's sign and zero offset."""
    sign = robot.signs[joint_index]
    return (angle_rad - robot.zero_offsets_rad[joint_index]) * sign / RAD_PER_TICK + CENTER_TICKS


class SimHand:
    """Bends limp joints of the simulated robot, as a person would. Thread-safe (the chain locks)."""

    def __init__(self, robot: RobotConfig, chain: Any) -> None:
        self.robot = robot
        self._chain = chain

    def set_angle(self, joint_index: int, angle_rad: float) -> None:
        """Pose joint ``joint_index`` (0-based, config order) at ``angle_rad``; ValueError if it holds torque."""
        servo_id = self.robot.joint_ids[joint_index]
        self._chain.set_limp_position(servo_id, ticks_from_angle(self.robot, joint_index, angle_rad))

    def set_ticks(self, servo_id: int, ticks: float) -> None:
        self._chain.set_limp_position(servo_id, ticks)

    def set_pose(self, angles_rad: Sequence[float]) -> None:
        for j, angle in enumerate(angles_rad):
            self.set_angle(j, float(angle))

    def let_go(self) -> None:
        """Let go of every joint bent so far. In the physics lab the hand holds a bent joint against gravity (as a
        person holds the robot in shape) until its torque goes on or the hand lets go; the scripted lab's limp
        joints stay where they were put anyway."""
        self._chain.release_limp_hold()


def sim_hand_for(robot: RobotConfig) -> SimHand | None:
    """A :class:`SimHand` when the robot is on the simulated lab (port ``sim``), else None (a real robot has a
    real person to pose it)."""
    if not is_sim(robot.port):
        return None
    from devices.factory import sim_lab

    return SimHand(robot, sim_lab().chain)
