"""The errors app.core raises, in one place: each names what went wrong and what to do, and also inherits the builtin a
caller would expect (a bad file is a ValueError, a lost link a ConnectionError).
"""

from __future__ import annotations


# raised by app.core.calfiles
class CalFileError(ValueError):
    """A calibration, trial or series file is malformed. The message names the file (and line) and the fix."""


# raised by app.core.live_session
class BoardSilentError(TimeoutError):
    """The port opened but no valid frame arrived."""


# raised by app.core.live_session
class BoardGoneError(ConnectionError):
    """The recording ended with the board unplugged or silent; everything before is in the file."""


# raised by app.core.recording
class RecordingError(OSError):
    """Writing a recording failed (disk full, file gone); what was flushed before stays readable."""


# raised by app.core.recording
class RecordingFormatError(ValueError):
    """A file is not a SenSnake recording this version can read; the message names the file."""


# raised by app.core.servo_settings
class SettingsError(ValueError):
    """A settings request that cannot be carried out (unknown item, out of range, read-only, a bad file)."""


# raised by app.core.rig_protocol
class BoardStreamError(RuntimeError):
    """The sensor's conductance stopped arriving from the board."""


# raised by app.core.rig_protocol
class TrialGapError(RuntimeError):
    """A trial's record has a gap too long to bridge: the trial is run again, not kept."""


# raised by app.core.rig_protocol
class BoardGapError(BoardStreamError, TrialGapError):
    """A trial's board samples have a gap too long to bridge (frames lost): the trial is run again, not kept."""


# raised by app.core.rig_protocol
class RigReadGapError(TrialGapError):
    """The rig's force went unread over a trial's loading edge for too long (a busy computer): the trial is run
    again, not kept."""


# raised by app.core.rig_protocol
class ForceCollapsedError(RuntimeError):
    """The reading collapsed during a hold: the cable snapped or the probe slipped off the sensor."""


# raised by app.core.sweep
class SweepError(ValueError):
    """A sweep file that cannot be run; the message names the file and the key."""


# raised by app.core.shapes
class ShapeFormatError(ValueError):
    """A shape file is unreadable, of an unknown format/version, or has a missing or bad key (named)."""


# raised by app.core.outputs
class OutputPathError(OSError):
    """An output path no writer may replace: a device, FIFO, socket or folder, or a symbolic link loop (named)."""


# raised by app.core.mocap
class MocapFileError(ValueError):
    """A motion-capture take that cannot be read or placed (no layout labels, unknown units, too few markers a
    segment, no MoCap stream), or an output that would replace a file; the message names the file and the cause."""


# raised by app.core.repeatability
class RepeatabilityError(ValueError):
    """Recordings that cannot be compared as trials (too few, invalid, of different conditions); names the file."""


# raised by app.core.trials
class TrialsError(ValueError):
    """A trial series that cannot be run or resumed; the message names the folder or file and the cause."""


class InvalidRunError(RuntimeError):
    """The physics stopped being physics before the capture (in the settle): there is no run to record."""


class InvalidRecordingError(ValueError):
    """The recording is of a run whose physics stopped being physics (``/sim`` ``valid`` = 0): no check of it is data."""


# raised by app.core.engines
class EngineError(ConnectionError):
    """The runs' engine cannot start or be reached (a Dask scheduler that does not answer); names the address."""


# raised by app.core.engines
class FolderBusyError(RuntimeError):
    """Another sweep, evaluation or tuning is writing into the folder (its lock is held); names the folder."""


# raised by app.core.engines
class RunsInterrupted(KeyboardInterrupt):
    """Ctrl-C, SIGTERM or SIGHUP while runs were going on: pending runs cancelled, workers stopped; what finished is
    kept (``finished`` of ``total``) and the same command resumes."""

    def __init__(self, finished: int = 0, total: int = 0, signal_name: str = "SIGINT") -> None:
        super().__init__(f"{signal_name}: {finished} of {total} runs finished")
        self.finished, self.total, self.signal_name = finished, total, signal_name


# raised by app.core.evaluate
class EvaluationError(ValueError):
    """An evaluation file that cannot be run, or a folder that holds another evaluation; names the file and key."""


# raised by app.core.tune
class TuneError(ValueError):
    """A tuning file that cannot be run, or a folder that holds another study; names the file and key."""


# raised by app.core.series
class PlotLayoutError(ValueError):
    """A plot layout file that cannot be read (not JSON, another format or version, a bad key); names the file."""
