"""The physics lab: SenSnake v2, the ground and the paper's half-cylindrical obstacle simulated in MuJoCo.

:mod:`.model` writes the MJCF scene, :mod:`.world` steps it and reads joint states and per-sensor contact forces.
The world sits *under* the simulated servo chain and board (``devices.sim.dxl_chain``, ``devices.sim.board``), so
drivers talk to it through the wire exactly as to the scripted lab. ``mujoco`` is imported only here, so nothing
else pays for it.
"""

import os
import sys

# Headless Linux renders the 3-D view through EGL (no X server needed); elsewhere MuJoCo picks its default. Must be
# set before ``mujoco`` is first imported, which happens only inside this package.
if sys.platform.startswith("linux"):
    os.environ.setdefault("MUJOCO_GL", "egl")
