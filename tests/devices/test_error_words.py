"""devices.errors.os_words: the OS's reason once, in words — from pyserial's echo, from
termios.error (no OSError) and from a plain OSError."""

from __future__ import annotations

import errno
import os
import termios

import pytest
import serial

from devices.errors import os_words


def test_pyserial_echo_becomes_the_oss_words(tmp_path):
    with pytest.raises(serial.SerialException) as raised:
        serial.Serial(str(tmp_path / "ttyNOPE"))
    assert "[Errno 2]" in str(raised.value)  # what pyserial says, so this test means something
    assert os_words(raised.value) == os.strerror(errno.ENOENT)


def test_termios_error_and_oserror():
    assert os_words(termios.error(errno.EIO, "Input/output error")) == os.strerror(errno.EIO)
    assert os_words(OSError(errno.EISDIR, "Is a directory")) == os.strerror(errno.EISDIR)
    assert os_words(serial.SerialException("device reports readiness to read but returned no data")) == \
        "device reports readiness to read but returned no data"


def test_a_device_gone_away_reads_the_same_whichever_error_the_read_met_first():
    """A pty whose far end closed gave EIO on one read and pyserial's end-of-file words on another: the same loss,
    said two ways (a test comparing the app's and the loop process's messages failed on that)."""
    from devices.errors import link_lost_words

    gone = {link_lost_words(termios.error(errno.EIO, "Input/output error")),
            link_lost_words(OSError(errno.ENXIO, os.strerror(errno.ENXIO))),
            link_lost_words(serial.SerialException("device reports readiness to read but returned no data (device "
                                                   "disconnected or multiple access on port?)"))}
    assert len(gone) == 1 and "went away" in gone.pop()
    assert link_lost_words(OSError(errno.EACCES, os.strerror(errno.EACCES))) == os.strerror(errno.EACCES)
