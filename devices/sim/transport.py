"""An in-process serial port whose far end is a simulated device.

:class:`SimSerial` is a pyserial ``SerialBase``: dynamixel-sdk's ``PortHandler`` and the board reader use it exactly
as they use ``serial.Serial``. The far end is a :class:`SimEndpoint` that receives the host's bytes with a time stamp
and hands back the bytes whose arrival time (baud-rate time, return delay, frame period) has passed. Works the same on
every OS: no pseudo-terminal is needed (``devices/sim/pty_server.py`` serves an endpoint on a real pty for Linux tests).
"""

from __future__ import annotations

import threading
import time
from typing import Protocol

import serial


class SimEndpoint(Protocol):
    """The device side of a simulated serial link. Called from the thread that owns the port."""

    def host_opened(self, baud: int) -> None:
        """The host opened the port (or changed its baud rate)."""

    def host_closed(self) -> None:
        """The host closed the port."""

    def host_write(self, data: bytes, now_s: float) -> None:
        """Bytes the host wrote at monotonic time ``now_s`` (raise ``serial.SerialException`` if unplugged)."""

    def host_read(self, now_s: float) -> bytes:
        """Bytes that have arrived at the host by ``now_s`` (raise ``serial.SerialException`` if unplugged)."""


POLL_INTERVAL_S = 0.0002


class SimSerial(serial.SerialBase):
    """pyserial-compatible port connected to a :class:`SimEndpoint`."""

    is_open: bool

    def __init__(self, endpoint: SimEndpoint, *args, **kwargs) -> None:
        self._endpoint = endpoint
        self._rx = bytearray()
        self._lock = threading.Lock()
        super().__init__(*args, **kwargs)

    # -- pyserial SerialBase interface ---------------------------------------------------------------------------
    def open(self) -> None:
        if self.is_open:
            raise serial.SerialException("port already open")
        self.is_open = True
        self._endpoint.host_opened(int(self._baudrate))

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            self._endpoint.host_closed()

    def _reconfigure_port(self, force_update: bool = False) -> None:
        if self.is_open:
            self._endpoint.host_opened(int(self._baudrate))

    @property
    def in_waiting(self) -> int:
        self._pull()
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise serial.PortNotOpenError()
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        while True:
            self._pull()
            if len(self._rx) >= size:
                break
            if deadline is not None and time.monotonic() >= deadline:
                break
            time.sleep(POLL_INTERVAL_S)
        with self._lock:
            out = bytes(self._rx[:size])
            del self._rx[:size]
        return out

    def write(self, data) -> int:
        if not self.is_open:
            raise serial.PortNotOpenError()
        payload = bytes(data)
        self._endpoint.host_write(payload, time.monotonic())
        return len(payload)

    def flush(self) -> None:
        """Writes are delivered at once; nothing to wait for."""

    def reset_input_buffer(self) -> None:
        self._pull()
        with self._lock:
            self._rx.clear()

    def reset_output_buffer(self) -> None:
        """Writes are delivered at once; nothing is buffered."""

    # -- internals ------------------------------------------------------------------------------------------------
    def _pull(self) -> None:
        if not self.is_open:
            raise serial.PortNotOpenError()
        data = self._endpoint.host_read(time.monotonic())
        if data:
            with self._lock:
                self._rx += data
