"""Nothing a user types loses data: an output onto one of the command's inputs is refused before
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

    from app.core.errors import RecordingError
    from app.core.recording import RecordingWriter

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


# Runs `python -m app ARGV` as a child of a small, fresh python and prints its exit code, peak RSS (kB) and wall
# time: a child forked from this test process would start with (and report) the test process's own RSS.
_MEASURE = """
import os, subprocess, sys, time
start = time.monotonic()
child = subprocess.Popen([sys.executable, "-m", "app", *sys.argv[1:]], stdout=subprocess.DEVNULL)
_pid, status, usage = os.wait4(child.pid, 0)
print(os.waitstatus_to_exitcode(status), usage.ru_maxrss, time.monotonic() - start, file=sys.stdout)
"""


def _peak_rss_and_time(argv: list[str]) -> tuple[int, float, str, float]:
    """Run ``python -m app ARGV``; its exit code, its own peak RSS (MB), its stderr and wall time (s)."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", _MEASURE, *argv], capture_output=True, text=True, timeout=120)
    code, peak_kb, seconds = done.stdout.split()
    return int(code), int(peak_kb) / 1024, done.stderr, float(seconds)  # Linux: ru_maxrss in kB


def test_a_2_gb_sparse_csv_is_refused_in_bounded_memory_and_time(tmp_path):
    """`truncate -s 2G` after a header (estimate once grew to 24 GB and was killed): refused as not text, peak
    RSS ≤ 500 MB, ≤ 10 s, one line naming the file."""
    from tests.calibration_files import write_typical_calibration

    big = tmp_path / "big.csv"
    big.write_text("time_s,S06B\n", encoding="utf-8")
    with big.open("r+b") as handle:
        handle.truncate(2 << 30)
    cal = write_typical_calibration(tmp_path / "cal.json", ["S06B"])
    for argv in (["estimate", str(big), "--cal", str(cal), "--out", str(tmp_path / "f.csv")],
                 ["fit", str(big), "--sensor", "S06B", "--area", "0.0014", "--out", str(tmp_path / "c.json")]):
        code, peak_mb, err, seconds = _peak_rss_and_time(argv)
        assert code == 1 and "Traceback" not in err, err[-2000:]
        assert len(err.strip().splitlines()) == 1 and str(big) in err and "not a text CSV" in err, err
        assert peak_mb <= 500 and seconds <= 10, (peak_mb, seconds)
    assert not (tmp_path / "f.csv").exists() and not (tmp_path / "c.json").exists()


def test_a_line_too_long_to_be_a_row_and_a_nul_in_the_middle_are_one_line_each(tmp_path, capsys):
    from tests.calibration_files import write_typical_calibration

    cal = write_typical_calibration(tmp_path / "cal.json", ["S06B"])
    long_line = tmp_path / "long.csv"
    long_line.write_text("time_s,S06B\n0,1e-4\n" + "1," + "9" * (3 << 20) + "\n2,1e-4\n", encoding="utf-8")
    nul = tmp_path / "nul.csv"
    nul.write_bytes(b"time_s,S06B\n0,1e-4\n1,1e-4\n\x002,1e-4\n")
    for path, words in ((long_line, "longer than 1 MB"), (nul, "NUL byte")):
        assert main(["estimate", str(path), "--cal", str(cal), "--out", str(tmp_path / "f.csv")]) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(path) in err and words in err, err
    assert main(["estimate", str(nul), "--cal", str(cal), "--out", str(tmp_path / "f.csv")]) == 1
    assert "(line 4)" in capsys.readouterr().err


def test_record_under_a_file_size_limit_stops_with_one_line_and_a_file_that_opens(tmp_path):
    """`ulimit -f` standing in for a quota, a full network disk or an I/O error (once: exit 139 after four h5py
    tracebacks, and a file that no longer opened): exit 1, one error line naming the cause, no traceback, and the
    file opens with plain h5py holding what was flushed."""
    import resource
    import subprocess
    import sys

    import h5py

    out = tmp_path / "limited.h5"

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (600_000, 600_000))

    done = subprocess.run([sys.executable, "-m", "app", "record", "--daq", "sim", "--seconds", "60", "--out",
                           str(out)], preexec_fn=limit, capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr[-2000:]
    errors = [line for line in done.stderr.splitlines() if line.startswith("sensnake record: error")]
    assert len(errors) == 1 and "File too large" in errors[0] and str(out) in errors[0], done.stderr[-2000:]
    assert "Traceback" not in done.stderr and "Exception ignored" not in done.stderr
    with h5py.File(out, "r") as f:
        assert f["daq/seq"].shape[0] > 0 and f.attrs["format"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary or lock left behind


def test_an_out_that_is_a_symlink_loop_is_refused_before_recording_leaving_nothing(tmp_path, capsys):
    (tmp_path / "a.h5").symlink_to(tmp_path / "b.h5")
    (tmp_path / "b.h5").symlink_to(tmp_path / "a.h5")
    assert main(["record", "--daq", "sim", "--seconds", "5", "--out", str(tmp_path / "a.h5")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len([line for line in err if "error" in line]) == 1 and "a.h5" in err[-1] and "symbolic link loop" in err[-1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5", "b.h5"]  # no hidden temporary, no lock left


def test_a_non_numeric_cell_is_a_flagged_gap_not_a_refused_file(tmp_path, capsys):
    """One `ERR` cell once refused the whole estimate file (a NaN in its place was handled per sample)."""
    import csv

    from tests.calibration_files import write_typical_calibration

    cal = write_typical_calibration(tmp_path / "cal.json", ["S06B", "S07B"])
    rows = [f"{k / 30:.6f},{1e-4 * (1 + k % 5)},{2e-4}" for k in range(60)]
    rows[10] = rows[10].rsplit(",", 2)[0] + ",ERR," + "2e-4"
    rows[20] = rows[20].rsplit(",", 2)[0] + ",--," + "2e-4"
    data = tmp_path / "in.csv"
    data.write_text("time_s,S06B,S07B\n" + "\n".join(rows) + "\n")
    out = tmp_path / "f.csv"
    assert main(["estimate", str(data), "--cal", str(cal), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    warned = [line for line in err.splitlines() if "non-numeric" in line]
    assert len(warned) == 1 and "S06B: 2 non-numeric cell(s) read as gaps (first at line 12: 'ERR')" in warned[0]
    with out.open() as handle:
        table = list(csv.reader(handle))
    assert table[11][1] in ("", "nan") and table[21][1] in ("", "nan") and table[12][1] not in ("", "nan")
    assert all(row[2] not in ("", "nan") for row in table[1:])  # the other sensor untouched
    # A column with no number at all is refused (one line), and text where the time is too.
    text_column = tmp_path / "text.csv"
    text_column.write_text("time_s,S06B\n0,ERR\n0.1,ERR\n")
    assert main(["estimate", str(text_column), "--cal", str(cal), "--out", str(out)]) == 1
    assert "holds no number at all" in capsys.readouterr().err
    text_time = tmp_path / "time.csv"
    text_time.write_text("time_s,S06B\n0,1e-4\nsoon,1e-4\n")
    assert main(["estimate", str(text_time), "--cal", str(cal), "--out", str(out)]) == 1
    assert "time.csv:3: column 'time_s' holds 'soon'" in capsys.readouterr().err


def test_an_output_never_replaces_a_recording_but_a_copy_of_the_same_run_may_be_made_again(tmp_path, capsys):
    """A CSV, another run or another run's copy written over a recording lost raw data nothing else holds (exit 0,
    no word). A repair or estimate of a recording may replace its own earlier copy."""
    import hashlib

    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    for path in (a, b):
        assert main(["record", "--daq", "sim", "--seconds", "0.5", "--out", str(path)]) == 0
    capsys.readouterr()
    digest = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in (a, b)}
    for argv in (["export", str(a), "--csv", str(b)],
                 ["repair", str(a), "--out", str(b)],
                 ["record", "--daq", "sim", "--seconds", "0.5", "--out", str(a)]):
        assert main(argv) == 1, argv
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "an output never replaces a recording" in err and "(run " in err, err
    assert {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in (a, b)} == digest
    copy = tmp_path / "a-copy.h5"
    assert main(["repair", str(a), "--out", str(copy)]) == 0
    assert main(["repair", str(a), "--out", str(copy)]) == 0  # the same run's copy, made again
    text = tmp_path / "notes.txt"
    text.write_text("not a recording\n", encoding="utf-8")
    assert main(["export", str(a), "--csv", str(text)]) == 0  # other files are replaced as before
