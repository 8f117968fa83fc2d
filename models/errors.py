"""The errors models raises, in one place: each names what went wrong and what to do, and also inherits the builtin a
caller would expect (a bad file is a ValueError, a lost link a ConnectionError).
"""

from __future__ import annotations


# raised by models.calibration
class FlatSensorError(ValueError):
    """A trial shows no usable response (flat-lined or disconnected sensor): the fit is refused."""


# raised by models.trajectory
class TrajectoryError(ValueError):
    """A requested trajectory cannot be made (bad shape, speed, or a keyframe step faster than the servos allow)."""


# raised by models.force_feedback
class GainsError(ValueError):
    """Gains out of their safe ranges; the message names the gain."""


# raised by models.mocap
class MocapLayoutError(ValueError):
    """A marker layout that cannot give a segment's pose (fewer than 3 markers, three on one line); names why."""


class OffsetRefusedError(ValueError):
    """The motion cannot fix where a motion-capture take sits on a recording's clock (no motion, too little
    overlap, an ambiguous or poor match); the message says which, with the numbers."""


# raised by models.shell_fit
class ShellFitError(ValueError):
    """A rig's force-deflection data that cannot give a shell's stiffness at all (no contact reached, a snapped cable,
    too few steps); the message names which, with the numbers."""
