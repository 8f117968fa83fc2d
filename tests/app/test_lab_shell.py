"""sensnake lab shell: the shell's bench test on the simulated rig (its shell the config's [lab.physics])."""

from __future__ import annotations

import pytest

from app.cli.main import main
from devices import factory
from devices.config import load_config

SCALE = "20"  # the simulated rig 20x real time, as the rig's own tests


def _config(tmp_path, stiffness: float):
    path = tmp_path / f"lab_{stiffness:g}.toml"
    path.write_text(f"[lab.physics]\nshell_stiffness_n_per_m = {stiffness}\n", encoding="utf-8")
    return path


@pytest.mark.parametrize("stiffness", [1400.0, 3000.0])
def test_recovers_a_non_default_shell_stiffness_and_writes_a_fragment_config_accepts(tmp_path, capsys, stiffness):
    out = tmp_path / "shell.toml"
    code = main(["lab", "shell", "--rig", "sim", "--config", str(_config(tmp_path, stiffness)), "--time-scale", SCALE,
                 "--out", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    fitted = load_config(out).lab.physical
    assert fitted.shell_stiffness_n_per_m == pytest.approx(stiffness, rel=0.10)
    line = next(x for x in printed.out.splitlines() if x.startswith("shell_stiffness_n_per_m"))
    low, high = (float(v) for v in line.split("95 %:")[1].split("fixed")[0].split(" to "))
    # A 95 % interval misses the truth in one run of twenty by design, and the simulated rig's runs differ (where
    # the contact search and the wheel stop depends on the machine's timing): the test holds the truth to the same
    # interval widened to 99.9 % (t at 15 degrees of freedom: 4.07 against 2.13), missed once in a thousand runs.
    # bench_shell measures the 95 % interval's coverage itself (27 of 30).
    centre, half = 0.5 * (low + high), 0.5 * (high - low) * 4.07 / 2.13
    assert centre - half < stiffness < centre + half
    assert high - low < 0.02 * stiffness  # and it is no wide net: ±1 %
    assert "shell_damping_n_s_per_m" in printed.err  # never fixed by readings at rest, never written
    if stiffness == 1400.0:  # bottoms out at 4.2 N of the ramp's 8: the travel is fixed too
        assert fitted.shell_travel_m == pytest.approx(0.003, rel=0.10)
    else:  # would need 9 N: not fixed, not written (the default stays)
        assert "shell_travel_m" not in out.read_text(encoding="utf-8").split("[lab.physics]")[1]


def test_never_replaces_a_file(tmp_path, capsys):
    existing = tmp_path / "shell.toml"
    existing.write_text("# mine\n", encoding="utf-8")
    assert main(["lab", "shell", "--rig", "sim", "--time-scale", SCALE, "--out", str(existing)]) == 1
    assert "never replaces" in capsys.readouterr().err and existing.read_text(encoding="utf-8") == "# mine\n"


def _faulty_bench(monkeypatch, fault):
    start = factory.start_sim_rig_bench

    def faulty(*args, **kwargs):
        bench, previous = start(*args, **kwargs)
        fault(bench.rig)
        return bench, previous

    monkeypatch.setattr(factory, "start_sim_rig_bench", faulty)


def _one_line_error(capsys) -> str:
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "Traceback" not in err[0]
    return err[0]


def test_a_snapped_cable_and_a_jammed_wheel_give_one_clear_line(tmp_path, capsys, monkeypatch):
    _faulty_bench(monkeypatch, lambda rig: rig.snap_cable())  # snapped before: no contact anywhere
    assert main(["lab", "shell", "--rig", "sim", "--time-scale", SCALE, "--out", str(tmp_path / "a.toml")]) == 1
    assert "no contact found" in _one_line_error(capsys)
    _faulty_bench(monkeypatch, lambda rig: rig.jam(0.5))
    assert main(["lab", "shell", "--rig", "sim", "--time-scale", SCALE, "--out", str(tmp_path / "b.toml")]) == 1
    assert "something holds the wheel" in _one_line_error(capsys)
    assert not (tmp_path / "a.toml").exists() and not (tmp_path / "b.toml").exists()


def test_a_cable_that_snaps_during_the_ramp_is_named(tmp_path, capsys, monkeypatch):
    travel_gauge = factory.travel_gauge

    def snapping(*args, **kwargs):
        gauge = travel_gauge(*args, **kwargs)
        read, reads = gauge.read_m, []

        def read_m(what):
            reads.append(what)
            if len(reads) == 10:  # six loaded steps in
                factory.installed_sim_lab().rig.snap_cable()
            return read(what)

        gauge.read_m = read_m
        return gauge

    monkeypatch.setattr(factory, "travel_gauge", snapping)
    assert main(["lab", "shell", "--rig", "sim", "--time-scale", SCALE, "--out", str(tmp_path / "c.toml")]) == 1
    assert "snapped" in _one_line_error(capsys)
    assert not (tmp_path / "c.toml").exists()


def test_a_probe_that_never_moves_is_no_contact_and_nothing_is_written(tmp_path, capsys):
    # a shell as stiff as the config allows (1e6 N/m): the probe goes 0.002 mm in at 8 N, below the gauge's 5 digits
    out = tmp_path / "d.toml"
    assert main(["lab", "shell", "--rig", "sim", "--config", str(_config(tmp_path, 1e6)), "--time-scale", SCALE,
                 "--out", str(out)]) == 1
    assert "no contact reached" in _one_line_error(capsys)
    assert not out.exists()


def test_typed_readings_take_the_same_path(tmp_path, capsys, monkeypatch):
    """The real rig's gauge is a person typing what the display shows: fed here from the simulated gauge's readings
    as a person would type them (mm, two decimals, a comma once, one blank line)."""
    from devices.gauge import TypedGauge

    travel_gauge = factory.travel_gauge

    def typed(port, resolution_m, **kwargs):
        simulated = travel_gauge(port, resolution_m, **kwargs)
        lines: list[str] = []

        def person(prompt: str) -> str:
            lines.append(prompt)
            if len(lines) == 2:
                return ""  # Enter pressed by mistake: asked again
            text = f"{simulated.read_m(prompt) * 1e3:.2f}"
            return text.replace(".", ",") if len(lines) == 5 else text

        return TypedGauge(resolution_m, ask=person)

    monkeypatch.setattr(factory, "travel_gauge", typed)
    out = tmp_path / "e.toml"
    assert main(["lab", "shell", "--rig", "sim", "--config", str(_config(tmp_path, 1400.0)), "--time-scale", SCALE,
                 "--out", str(out)]) == 0, capsys.readouterr().err
    assert load_config(out).lab.physical.shell_stiffness_n_per_m == pytest.approx(1400.0, rel=0.10)


def test_a_hold_names_a_shell_that_creeps(tmp_path, capsys, monkeypatch):
    args = ["lab", "shell", "--rig", "sim", "--time-scale", SCALE, "--hold", "20"]
    assert main([*args, "--out", str(tmp_path / "f.toml")]) == 0  # the simulated shell: a spring and a damper
    assert "no creep the gauge sees" in capsys.readouterr().out
    travel_gauge = factory.travel_gauge

    def creeping(*args, **kwargs):  # a viscoelastic shell: 0.05 mm further in at the end of the hold
        gauge = travel_gauge(*args, **kwargs)
        read = gauge.read_m
        gauge.read_m = lambda what: read(what) + (5e-5 if "held" in what else 0.0)
        return gauge

    monkeypatch.setattr(factory, "travel_gauge", creeping)
    assert main([*args, "--out", str(tmp_path / "g.toml")]) == 0
    assert "CREEP: held 20 s" in capsys.readouterr().out
    assert "CREEP" in (tmp_path / "g.toml").read_text(encoding="utf-8")


def test_the_calibration_bias_said_is_k_over_k_plus_the_shell(tmp_path, capsys):
    assert main(["lab", "shell", "--rig", "sim", "--config", str(_config(tmp_path, 1400.0)), "--time-scale", SCALE,
                 "--gauge-force", "1", "--gauge-rate", "150", "--out", str(tmp_path / "h.toml")]) == 0
    said = next(x for x in capsys.readouterr().out.splitlines() if "overstated by" in x)
    percent = float(said.split("overstated by ")[1].split(" %")[0])
    assert percent == pytest.approx(100 * 246 / (246 + 1400), abs=0.3)  # 14.9 %: the gauge is not there then
