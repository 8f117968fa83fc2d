"""Motion capture in the app: the control loop's beat while a 960 Hz motion-capture stream arrives.

The app as ``sensnake gui`` opens it, on a real X display (its own Xvfb, Qt's xcb platform): the physics lab with
``[lab] mocap = true`` (flat ground; the lab, its simulated PhaseSpace-like stream and the control loop each in their
own process, the stream followed by the app), a serpenoid gait playing, the Forces tab recording for SECONDS (60 by
default) while the 3-D tab draws the motion-captured markers over the simulated body and the kinematics panel draws
each segment's position against time. Prints the 50 Hz loop's ticks and missed ticks while the recording ran and
while its ``/mocap`` was then fitted and written, what the recording holds, and the machine's load (the figures are
worth what the load lets them be). ``--baseline`` runs the same without motion capture first, for comparison.

    python -m benchmarks.bench_mocap_gui [--seconds 60] [--baseline]

Discovery stays on this machine: the run uses a Lab Streaming Layer configuration that keeps it on the loopback
interface (``LSLAPICFG``; the app itself leaves LSL's configuration to the user). ``run(quick)`` (``sensnake bench``):
quick records 10 s. Each run is ``tests/realdisplay/mocap_probe.py``, also the real-display test's.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

TIMEOUT_S = 900.0


def probe(seconds: float, with_mocap: bool = True) -> dict:
    """One run of the probe on a private Xvfb; its result."""
    from app.core.lsl_link import LSL_LOOPBACK_CONFIG
    from tests.realdisplay.xserver import XServer, probe_env

    server = XServer.start()
    try:
        with tempfile.TemporaryDirectory(prefix="bench-mocap-") as tmp:
            config = Path(tmp) / "lsl_api.cfg"
            config.write_text(LSL_LOOPBACK_CONFIG, encoding="utf-8")
            env = probe_env(server.display)
            env["LSLAPICFG"] = str(config)
            command = [sys.executable, "-m", "tests.realdisplay.mocap_probe", str(seconds),
                       *([] if with_mocap else ["off"])]
            done = subprocess.run(command, cwd=Path(__file__).resolve().parents[1], env=env, capture_output=True,
                                  text=True, timeout=TIMEOUT_S + 2 * seconds)
    finally:
        server.stop()
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode != 0 or not lines:
        raise RuntimeError(f"the probe failed (exit {done.returncode}): {done.stdout[-1500:]} {done.stderr[-1500:]}")
    return json.loads(lines[-1])


def line(result: dict) -> str:
    """The result in one line, as docs/BENCHMARKS.md and docs/MOCAP.md quote it."""
    what = "with motion capture" if result["with_mocap"] else "without motion capture (baseline)"
    text = (f"{result['seconds']:g} s recorded {what}, serpenoid playing: loop {result.get('missed_ticks', '?')} "
            f"missed of {result.get('ticks', '?')} ticks at 50 Hz ({result.get('late_ticks', '?')} late), then "
            f"{result.get('missed_ticks_writing', '?')} missed of {result.get('ticks_writing', '?')} while /mocap was "
            f"written ({result['written_after_s'] - result['recorded_for_s']:.1f} s)")
    if result["with_mocap"]:
        text += (f"; /mocap {result.get('mocap_samples', 0)} samples at {result.get('mocap_rate_hz', 0):g} Hz, "
                 f"{100 * result.get('posed_fraction', 0):.1f} % of segment-frames posed, longest gap "
                 f"{1000 * (result.get('max_gap_s') or 0):.1f} ms, {result.get('stream_dropouts')} dropouts; "
                 f"3-D picture {result['views']['scene']['frames_per_s']:.1f} frames/s with "
                 f"{result['mocap_pixels']['scene']} marker pixels, kinematics panel "
                 f"{result['views']['kinematics_time']['frames_per_s']:.1f} frames/s")
    return text + f"; load average {result['load_average']:.1f} on {os.cpu_count()} CPUs"


def run(quick: bool = False, seconds: float | None = None, baseline: bool = False) -> list[dict]:
    seconds = seconds if seconds is not None else (10.0 if quick else 60.0)
    results = []
    for with_mocap in ((False, True) if baseline else (True,)):
        result = probe(seconds, with_mocap)
        print(line(result), flush=True)
        results.append(result)
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--baseline", action="store_true", help="run without motion capture first")
    parser.add_argument("--json", metavar="FILE", help="write the results there too")
    args = parser.parse_args()
    results = run(seconds=args.seconds, baseline=args.baseline)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1), encoding="utf-8")


if __name__ == "__main__":
    main()
