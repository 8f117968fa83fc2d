"""Shared look: sensor-side colours, status colours and sizes used by every widget.

Colours come from the Okabe–Ito palette so left/right/bottom traces stay distinguishable for colour-blind users and on
a projector. Plain hex strings (usable in pyqtgraph pens and Qt style sheets) plus :func:`qcolor` for QColor.
Any thread may read these constants; build QColor objects on the GUI thread.
"""

from __future__ import annotations

from typing import Any

from PySide6.QtGui import QColor

# Sensor sides (SPEC §2: channel k = 3·(segment−1) + {L:0, R:1, B:2}).
SIDE_COLORS: dict[str, str] = {
    "L": "#0072B2",  # blue
    "R": "#D55E00",  # vermillion
    "B": "#009E73",  # bluish green
}
SIDE_LABELS: dict[str, str] = {"L": "left", "R": "right", "B": "bottom"}

# Joint axes (SPEC §2: odd IDs pitch, even IDs yaw by default).
AXIS_COLORS: dict[str, str] = {"pitch": "#CC79A7", "yaw": "#56B4E9"}

# Status levels shared by the status bar, tables and labels.
OK = "ok"
WARN = "warn"
ERROR = "error"
IDLE = "idle"
STATUS_COLORS: dict[str, str] = {
    OK: "#1B7F3B",
    WARN: "#B36B00",
    ERROR: "#C62828",
    IDLE: "#6B6B6B",
}
STATUS_BACKGROUNDS: dict[str, str] = {
    OK: "#E3F4E8",
    WARN: "#FFF1D6",
    ERROR: "#FDE2E2",
    IDLE: "#EFEFEF",
}

STOP_RED = "#D32F2F"
STOP_RED_PRESSED = "#9A0007"

# Series that are told apart only by colour (calibration trials, overlaid recordings), Okabe–Ito order.
SERIES_COLORS: tuple[str, ...] = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000",
                                  "#F0E442")

# Goal versus present overlays (Teach/Gait body drawing, plots).
GOAL_COLOR = "#7F7F7F"
PRESENT_COLOR = "#222222"

# Force colour map end points (no force → light grey, full scale → dark red).
FORCE_ZERO_COLOR = "#E0E0E0"
FORCE_FULL_COLOR = "#B2182B"

MONOSPACE_FAMILY = "monospace"


def qcolor(hex_color: str, alpha: int = 255) -> QColor:
    """A QColor from one of the hex strings above; ``alpha`` 0…255."""
    color = QColor(hex_color)
    color.setAlpha(alpha)
    return color


def series_color(index: int) -> str:
    """Colour of the ``index``-th series (cycles through :data:`SERIES_COLORS`)."""
    return SERIES_COLORS[index % len(SERIES_COLORS)]


def side_of(sensor_name: str) -> str:
    """The side letter of a sensor name such as ``S06B`` (the last character)."""
    side = sensor_name[-1:].upper()
    if side not in SIDE_COLORS:
        raise ValueError(f"sensor name {sensor_name!r} does not end in one of {', '.join(SIDE_COLORS)}")
    return side


def sensor_color(sensor_name: str) -> str:
    """The trace colour of a sensor, by its side."""
    return SIDE_COLORS[side_of(sensor_name)]


def force_color(force_n: float, full_scale_n: float) -> str:
    """Hex colour for a force on a linear grey → red ramp; ``full_scale_n`` maps to the darkest red."""
    if full_scale_n <= 0:
        raise ValueError(f"full_scale_n must be positive, got {full_scale_n}")
    fraction = min(max(force_n / full_scale_n, 0.0), 1.0)
    zero, full = QColor(FORCE_ZERO_COLOR), QColor(FORCE_FULL_COLOR)
    mix = [round(a + (b - a) * fraction) for a, b in
           ((zero.red(), full.red()), (zero.green(), full.green()), (zero.blue(), full.blue()))]
    return "#{:02X}{:02X}{:02X}".format(*mix)


def status_style(level: str) -> str:
    """A style sheet for a small status label at ``level`` (ok / warn / error / idle)."""
    return (f"color: {STATUS_COLORS[level]}; background: {STATUS_BACKGROUNDS[level]};"
            "border-radius: 3px; padding: 1px 6px;")


def no_si_prefix(axis: Any) -> None:
    """Numbers on a pyqtgraph ``axis`` in its own unit, never rescaled with an SI prefix ("N (x0.001)" was misread
    beside plots in other scales). pyqtgraph 0.14's ``enableAutoSIPrefix(False)`` alone keeps the scale of the range
    shown at that moment: called while a plot held only micro-newtons, it drew 2 N as "2e+06" for ever after. With no
    range left in which a prefix applies, the scale is 1 whatever the range."""
    axis.setSIPrefixEnableRanges(())
    axis.enableAutoSIPrefix(False)
