"""Sensor-health soak on the physics lab: the app as ``sensnake gui`` runs it (lab and loop in their own processes),
a walk — J2, J4, J6 bent (yaw) on flat ground, captured, played follow-the-leader, over and over — or any
other scene and shape, the Forces tab's health monitor watching all 36 healthy simulated sensors. Every alarm is printed with its time, sensor and words; a healthy lab raises none
``saturated`` is a true flag, not a false alarm: it means the force is above the readout's ceiling.

``python -m benchmarks.bench_health_soak [--seconds 600] [--speed 0.034] [--scene flat] [--pitch]`` (offscreen Qt;
the lab's processes are real). ``--pitch`` adds pitch bends (J3, J5) to the shape.
"""

from __future__ import annotations

import argparse
import time


def run(seconds: float, speed_rad_s: float, scene: str = "flat", pitch: bool = False) -> list[tuple[float, str, str]]:
    from dataclasses import replace

    from app.core.shapes import Shape
    from app.gui.robot_bridge import MOTION_RUNNING
    from benchmarks.app_session import app_session
    from devices.config import LabConfig, SimLabConfig
    from models.health import describe

    config = replace(LabConfig(), lab=SimLabConfig(physics="mujoco", scene=scene))
    angles = [0.0] * 12
    angles[1], angles[3], angles[5] = 0.5, -0.6, 0.5  # J2, J4, J6: yaw
    if pitch:
        angles[2], angles[4] = -0.3, -0.3  # J3, J5
    alarms: list[tuple[float, str, str]] = []
    with app_session("bench_health_soak", config, Shape("bent", tuple(config.robot.axes), tuple(angles))) as (
            lab, forces, gait, pump):
        pump(6_000)  # the limp robot settles on the scene
        gait.panel.set_mode("follow")
        gait.panel.speed_spin.setValue(speed_rad_s)
        gait.panel.repeat_spin.setValue(1000)  # played over and over until the time is up
        gait.panel.play_button.click()
        pump(20_000, until=lambda: lab.robot.motion_state == MOTION_RUNNING)
        started = time.monotonic()
        names = config.board.channel_names
        previous = forces.health.flags.copy()
        while time.monotonic() - started < seconds:
            pump(250)
            flags = forces.health.flags
            for i in range(len(names)):
                if flags[i] != previous[i] and flags[i]:
                    alarms.append((time.monotonic() - started, names[i], describe(int(flags[i]))))
            previous = flags.copy()
    return alarms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--speed", type=float, default=0.034)
    parser.add_argument("--scene", default="flat")
    parser.add_argument("--pitch", action="store_true")
    args = parser.parse_args()
    alarms = run(args.seconds, args.speed, args.scene, args.pitch)
    false = [a for a in alarms if a[2] != "saturated"]
    print(f"health soak: {args.seconds:.0f} s of follow-the-leader at {args.speed:g} rad/s on {args.scene}, "
          f"36 healthy simulated sensors: {len(false)} false alarm(s), {len(alarms) - len(false)} saturated")
    for t, name, words in alarms:
        print(f"  t = {t:6.1f} s  {name}: {words}")


if __name__ == "__main__":
    main()
