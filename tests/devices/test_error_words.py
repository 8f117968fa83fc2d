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
