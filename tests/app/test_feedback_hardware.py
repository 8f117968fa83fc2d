"""Force feedback on the real robot and board (skipped unless SENSNAKE_HARDWARE=1). The README's first-run procedure:
robot lying straight on flat ground, calibrated bottom sensors, small gains; then the obstacle.

    SENSNAKE_HARDWARE=1 SENSNAKE_CONFIG=my_lab.toml SENSNAKE_CAL=cal.json pytest -k feedback_on_the_robot
"""

from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest

from app.core.force_control import FeedbackProgress, ForceFeedbackMotion, ForcePage
from app.core.forces_pipeline import ForcesPipeline
from app.core.live_session import LiveSession
from devices.board import BoardReader
from devices.config import LabConfig, load_config
from devices.controller import RobotController
from devices.servo_chain import ServoChain
from models.force_feedback import FeedbackGains
from models.health import HealthMonitor
from models.trajectory import FollowTheLeader


@pytest.mark.hardware
def test_feedback_on_the_robot_small_gains_flat_ground(tmp_path):
    config = load_config(os.environ["SENSNAKE_CONFIG"]) if "SENSNAKE_CONFIG" in os.environ else LabConfig()
    pipeline = ForcesPipeline(config.board.channel_names)
    pipeline.load_calibration(os.environ["SENSNAKE_CAL"])
    page = ForcePage.create(config.board.n_channels, folder=tmp_path)
    live = LiveSession(config.board, pipeline=pipeline, health=HealthMonitor(config.board.n_channels,
                                                                              config.board.rate_hz), force_page=page)
    shape = np.zeros(config.robot.n_joints)
    shape[[2, 4, 6]] = -0.15  # a gentle vertical wave
    gains = FeedbackGains(conform_gain=0.05, push_gain=0.05, max_node_rad=0.1, max_correction_rad=0.15)
    motion = ForceFeedbackMotion(FollowTheLeader(shape, config.robot.axes, 0.034), tuple(config.robot.axes),
                                 tuple(config.board.channel_names), gains, page_path=str(page.path),
                                 joint_min_rad=tuple(config.robot.joint_min_rad),
                                 joint_max_rad=tuple(config.robot.joint_max_rad))
    with BoardReader(config.board) as reader, ServoChain(config.robot) as chain:
        chain.check_models()
        controller = RobotController(chain, config.robot)
        controller.start()
        try:
            future = controller.play(motion, "feedback, first run")
            ages = []
            deadline = time.monotonic() + 20.0
            while time.monotonic() < deadline:
                block = reader.read_block()
                if block is not None and len(block):
                    live.process_block(block)
                if isinstance(motion.progress, FeedbackProgress) and math.isfinite(motion.progress.force_age_s):
                    ages.append(motion.progress.force_age_s)
                # Deliberate: the GUI's drain rate (this test plays the GUI thread).
                time.sleep(1 / 60)
            controller.emergency_stop()
            assert future.result(timeout=5.0) in ("stopped", "finished")
        finally:
            controller.close()
            page.close()
    assert ages and np.median(ages) < 1 / config.board.rate_hz + 1 / config.robot.control_rate_hz + 1 / 60
