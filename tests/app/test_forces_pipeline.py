"""app/core/forces_pipeline.py: per-sensor status from a calibration file and live estimation on real models."""

from __future__ import annotations

import numpy as np
import pytest

from app.core.forces_pipeline import CALIBRATED, UNCALIBRATED, ForcesPipeline
from devices.config import default_sensor_names
from models.linear import LinearModel
from models.physics import DEFAULT_PHYSICS
from models.sls import TYPICAL_AREA_M2, TYPICAL_SLS, conductance_from_force
from tests.calibration_files import typical_sensor_entry, write_calibration

NAMES = default_sensor_names()


def test_sls_recovers_a_constant_force_from_the_models_forward_conductance(tmp_path):
    pipeline = ForcesPipeline(NAMES)
    pipeline.load_calibration(write_calibration(tmp_path / "cal.json", {"S06B": typical_sensor_entry()}))
    assert pipeline.status[NAMES.index("S06B")] == CALIBRATED
    assert pipeline.status.count(UNCALIBRATED) == 35
    t = np.arange(0, 60, 1 / 30)
    truth = conductance_from_force(t, np.full(t.size, 3.0), TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
    conductance = np.full((t.size, 36), 2e-4)
    conductance[:, NAMES.index("S06B")] = np.asarray(truth).ravel()
    forces = np.concatenate([pipeline.process(t[i:i + 7], conductance[i:i + 7]).force_n
                             for i in range(0, t.size, 7)])
    s06b = forces[:, NAMES.index("S06B")]
    assert s06b[-1] == pytest.approx(3.0, rel=0.02)  # creep-aware: right after a minute of creep
    assert np.isnan(np.delete(forces, NAMES.index("S06B"), axis=1)).all()
    display = pipeline.process(t[-1:] + 1 / 30, conductance[-1:]).display
    assert display[0, 0] == pytest.approx(200.0)  # uncalibrated sensors plot conductance in µS


def test_without_a_calibration_file_no_sensor_is_shown_as_newtons(tmp_path):
    """An uncalibrated sensor is never shown as newtons: with no file at all every sensor plots its conductance in
    µS (no typical-sensor stand-in, no hidden physics constants), whichever estimator; loading a file gives forces to
    the sensors it holds, clearing it takes them away again."""
    for kind in ("sls", "linear"):
        pipeline = ForcesPipeline(NAMES, estimator=kind)
        assert set(pipeline.status) == {UNCALIBRATED} and not pipeline.estimated.any()
        text, level = pipeline.summary()
        assert level == "warn" and "no calibration file" in text and "µS, not N" in text
        out = pipeline.process(np.array([0.0, 0.1]), np.full((2, 36), 3.5e-4))
        assert np.isnan(out.force_n).all() and out.display == pytest.approx(np.full((2, 36), 350.0))
        assert pipeline.label(0) == "S01L (µS, uncal.)"
    entry = typical_sensor_entry() | {"linear": {"m_S_per_N": 1e-4, "d_S": 5e-5}}
    pipeline.load_calibration(write_calibration(tmp_path / "cal.json", {"S01L": entry}))
    out = pipeline.process(np.array([0.0, 0.1]), np.full((2, 36), 3.5e-4))
    model = LinearModel(m_S_per_N=1e-4, d_S=5e-5)
    assert out.force_n[0, 0] == pytest.approx(float(model.force_from_conductance(np.array([3.5e-4]))[0]))
    assert np.isnan(out.force_n[:, 1:]).all() and pipeline.label(0) == "S01L"
    pipeline.clear_calibration()
    assert set(pipeline.status) == {UNCALIBRATED} and "no calibration file" in pipeline.summary()[0]
    assert np.isnan(pipeline.process(np.array([0.2]), np.full((1, 36), 3.5e-4)).force_n).all()


def test_unusable_entry_is_explained_and_clock_restart_recovers(tmp_path):
    pipeline = ForcesPipeline(NAMES)
    bad = typical_sensor_entry()
    bad["sls"]["E0_Pa"] = "soft"
    pipeline.load_calibration(write_calibration(tmp_path / "cal.json", {"S02R": bad, "S03B": typical_sensor_entry()}))
    assert pipeline.status[NAMES.index("S02R")] == UNCALIBRATED
    assert any("S02R" in problem and "E0_Pa" in problem for problem in pipeline.problems)
    pipeline.process(np.array([10.0, 10.1]), np.full((2, 36), 3e-4))
    restarted = pipeline.process(np.array([0.0, 0.1]), np.full((2, 36), 3e-4))  # board power-cycled
    assert np.isfinite(restarted.force_n[:, NAMES.index("S03B")]).all()
    backwards_inside = pipeline.process(np.array([5.0, 4.0]), np.full((2, 36), 3e-4))
    assert np.isnan(backwards_inside.force_n).all() and "backwards" in pipeline.last_block_problem
    with pytest.raises(ValueError, match="estimator"):
        pipeline.set_estimator("magic")


def test_degenerate_sls_fit_shows_conductance_and_says_why(tmp_path):
    """The live view never uses a fit that 'sensnake fit' marked degenerate (estimate refuses it too)."""
    degenerate = typical_sensor_entry() | {"degenerate": True,
                                "degenerate_reasons": ["no creep is resolved: τ → 0 and τ → ∞ both look elastic"]}
    pipeline = ForcesPipeline(NAMES)
    pipeline.load_calibration(write_calibration(tmp_path / "cal.json", {"S01L": degenerate, "S01R": typical_sensor_entry()}))
    assert pipeline.status[NAMES.index("S01L")] == UNCALIBRATED
    assert pipeline.status[NAMES.index("S01R")] == CALIBRATED
    assert any("S01L" in p and "degenerate" in p and "no creep is resolved" in p for p in pipeline.problems)
    out = pipeline.process(np.array([0.0, 0.1]), np.full((2, 36), 3e-4))
    assert np.isnan(out.force_n[:, NAMES.index("S01L")]).all()
    assert out.display[0, NAMES.index("S01L")] == pytest.approx(300.0)  # µS, labelled uncalibrated


def test_live_glitch_above_the_boards_ceiling_is_rejected_not_fed_to_the_creep_state(tmp_path):
    from app.core.live_session import LiveSession
    from devices.config import BoardConfig
    from models.sls import ForceStatus

    pipeline = ForcesPipeline(NAMES)
    pipeline.load_calibration(write_calibration(tmp_path / "cal.json", {"S06B": typical_sensor_entry()}))
    LiveSession(BoardConfig(), pipeline=pipeline)  # the session gives the pipeline its board's 1/R_C
    column = NAMES.index("S06B")
    t = np.arange(0, 20, 1 / 30)
    truth = np.asarray(conductance_from_force(t, np.full(t.size, 3.0), TYPICAL_SLS, TYPICAL_AREA_M2,
                                              DEFAULT_PHYSICS)).ravel()
    conductance = np.full((t.size, 36), 2e-4)
    conductance[:, column] = truth
    conductance[300, column] = 1e300
    out = pipeline.process(t, conductance)
    assert out.status[300, column] == ForceStatus.ABOVE_CEILING and np.isnan(out.force_n[300, column])
    assert np.allclose(out.force_n[301:, column], 3.0, rtol=1e-6)  # the state never saw the glitch
