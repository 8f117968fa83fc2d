"""A calibration file (SPEC §3.3) for tests that need sensors shown in newtons: every named sensor gets the models'
typical sensor (``models.sls.TYPICAL_SLS``, ``TYPICAL_AREA_M2``) and the default physics constants. Without a file
the app shows every sensor as conductance (µS), never as a force."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

from models.physics import DEFAULT_PHYSICS
from models.sls import TYPICAL_AREA_M2, TYPICAL_SLS


def typical_sensor_entry() -> dict:
    return {"area_m2": TYPICAL_AREA_M2, "sls": {"E0_Pa": float(TYPICAL_SLS.E0_Pa), "E1_Pa": float(TYPICAL_SLS.E1_Pa),
                                                "mu1_Pa_s": float(TYPICAL_SLS.mu1_Pa_s)}}


def write_calibration(path: Path, sensors: dict) -> Path:
    """Write ``sensors`` (name → entry) as a calibration file with the default physics; returns ``path``."""
    path.write_text(json.dumps({"format": "sensnake-calibration", "version": 1,
                                "physics": DEFAULT_PHYSICS.to_dict(), "sensors": sensors}), encoding="utf-8")
    return path


def write_typical_calibration(path: Path, names: Iterable[str]) -> Path:
    """Every sensor in ``names`` calibrated as the typical sensor; returns ``path``."""
    return write_calibration(path, {name: typical_sensor_entry() for name in names})
