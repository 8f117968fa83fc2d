"""Nothing a user types loses data (issue 25): an output onto one of the command's inputs is refused before
anything runs (the input untouched), and a baud rate no port can take is one usage line, never a traceback."""

from __future__ import annotations

import pytest

from app.cli.main import main


@pytest.mark.parametrize("command", [
    ["estimate", "{input}", "--cal", "{cal}", "--out", "{input}"],
    ["estimate", "{input}", "--cal", "{cal}", "--out", "{link}"],  # a symlink to the input is the input
    ["estimate", "{input}", "--cal", "{cal}", "--out", "{other}", "--flags", "{input}"],
    ["estimate", "{input}", "--cal", "{cal}", "--out", "{cal}"],
    ["forward", "{input}", "--cal", "{cal}", "--out", "{input}"],
    ["fit", "{input}", "{other}", "--sensor", "S06B", "--area", "0.0014", "--out", "{other}"],
    ["export", "{input}", "--csv", "{input}"],
    ["repair", "{input}", "--out", "{input}"],
])
def test_an_output_onto_an_input_is_refused_and_the_input_is_untouched(tmp_path, capsys, command):
    files = {name: tmp_path / f"{name}.dat" for name in ("input", "cal", "other")}
    for name, path in files.items():
        path.write_text(f"the {name} file\n", encoding="utf-8")
    link = tmp_path / "link.dat"
    link.symlink_to(files["input"])
    argv = [part.format(**{k: str(v) for k, v in files.items()}, link=str(link)) for part in command]
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "is also an input" in err and "Traceback" not in err
    for name, path in files.items():
        assert path.read_text(encoding="utf-8") == f"the {name} file\n"


@pytest.mark.parametrize("command", ["record", "scan"])
def test_a_baud_rate_no_port_can_take_is_one_line_never_a_traceback(capsys, command, tmp_path):
    argv = {"record": ["record", "--daq", "sim", "--seconds", "1", "--out", str(tmp_path / "r.h5")],
            "scan": ["scan", "--robot", "sim"]}[command]
    assert main([*argv, "--baud", "99999999999"]) == 1  # was an OverflowError traceback
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [f"sensnake {command}: error: --baud 99999999999 is faster than any serial port here "
                                "(at most 12000000 bps)"]
    assert not (tmp_path / "r.h5").exists()


def test_one_writer_per_recording_file_the_second_is_refused_naming_the_first(tmp_path):
    import os

    from app.core.recording import RecordingError, RecordingWriter

    path = tmp_path / "same.h5"
    first = RecordingWriter(path, "", ["S01B"])
    try:
        with pytest.raises(RecordingError, match=rf"same.h5 is being recorded by another process \(pid {os.getpid()}\)"):
            RecordingWriter(path, "", ["S01B"])
    finally:
        first.close()
    again = RecordingWriter(path, "", ["S01B"])  # the lock went with the first writer
    again.close()
    leftovers = [p.name for p in tmp_path.iterdir()]
    assert leftovers == []  # no data: nothing written, no lock file, no hidden temporary left


def test_the_hidden_temporary_is_never_opened_through_a_planted_symlink(tmp_path):
    from app.core.recording import RecordingWriter

    victim = tmp_path / "someone_elses.txt"
    victim.write_text("precious\n", encoding="utf-8")
    # a guess at the old predictable name (pid only) pointing at someone else's file
    import os

    (tmp_path / f".rec.h5.{os.getpid()}.partial").symlink_to(victim)
    writer = RecordingWriter(tmp_path / "rec.h5", "", ["S01B"])
    writer.close()
    assert victim.read_text(encoding="utf-8") == "precious\n"


def _calibration_of(tmp_path):
    import dataclasses
    import json

    from devices.config import LabConfig, SimLabConfig
    from devices.sim.lab import SimLab

    lab = SimLab(dataclasses.replace(LabConfig(), lab=SimLabConfig(physics="scripted")), seed=2)
    try:
        return json.loads(json.dumps(lab.board.ground_truth_calibration()))
    finally:
        lab.close()


def test_messages_about_a_bad_calibration_name_the_file_the_sensor_and_the_key(tmp_path, capsys):
    import json

    document = _calibration_of(tmp_path)
    document["sensors"]["S06B"]["sls"]["mu1_Pa_s"] = -5.0
    cal = tmp_path / "bad-cal.json"
    cal.write_text(json.dumps(document), encoding="utf-8")
    data = tmp_path / "in.csv"
    data.write_text("time_s,S06B\n0,0.0001\n0.1,0.0001\n", encoding="utf-8")
    assert main(["estimate", str(data), "--cal", str(cal), "--out", str(tmp_path / "out.csv")]) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"sensnake estimate: error: {cal}: sensor 'S06B' sls.mu1_Pa_s is -5.0, expected a positive number"
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000, encoding="utf-8")
    assert main(["estimate", str(data), "--cal", str(deep), "--out", str(tmp_path / "out.csv")]) == 1
    assert capsys.readouterr().err.strip() == (f"sensnake estimate: error: {deep}: nested too deeply to be a "
                                               "calibration file")


def test_a_semicolon_separated_file_is_named_for_what_it_is(tmp_path, capsys):
    data = tmp_path / "excel.csv"
    data.write_text("time_s;S06B\n0;0.0001\n", encoding="utf-8")
    import json

    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(_calibration_of(tmp_path)), encoding="utf-8")
    assert main(["estimate", str(data), "--cal", str(cal), "--out", str(tmp_path / "o.csv")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"sensnake estimate: error: {data}:1: the columns are separated by semicolons")
