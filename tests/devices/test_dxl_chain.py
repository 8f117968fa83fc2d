"""dynamixel-sdk's own PacketHandler and group classes against the simulated chain over SimSerial."""

from __future__ import annotations

import threading
import time

import pytest
import serial
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupBulkWrite,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from devices import control_table as ct
from devices import dxl_wire as wire
from devices.sim.clock import SimClock
from devices.sim.dxl_chain import VirtualChain
from devices.sim.transport import SimSerial

IDS = tuple(range(1, 13))
ACCESS, DATA_LIMIT, DATA_LENGTH, DATA_RANGE, CRC, RESULT_FAIL = 7, 6, 5, 4, 3, 1


class _SimPort(PortHandler):
    """The SDK's PortHandler with its serial port replaced by a SimSerial onto the virtual chain."""

    def __init__(self, endpoint, baud=1_000_000):
        super().__init__("sim")
        self._endpoint = endpoint
        self.baudrate = baud

    def setupPort(self, cflag_baud):  # noqa: N802
        if self.ser is None:
            self.ser = SimSerial(self._endpoint, port="sim", baudrate=self.baudrate, timeout=0)
        else:
            self.ser.baudrate = self.baudrate
        self.is_open = True
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def getCFlagBaud(self, baudrate):  # noqa: N802
        return baudrate


def wait_for_ping(port, ph, servo_id: int, timeout_s: float = 2.0) -> None:
    """Ping until ``servo_id`` answers again after a reboot or factory reset (which take simulated time); the
    caller's next assertion fails if it never does. Polls: the simulated chain advances with the wall clock."""
    deadline = time.monotonic() + timeout_s
    while ph.ping(port, servo_id)[1] != COMM_SUCCESS and time.monotonic() < deadline:
        pass


@pytest.fixture
def bus():
    chain = VirtualChain(ids=IDS, baud=1_000_000, clock=SimClock(20.0), seed=7)
    port = _SimPort(chain)
    assert port.openPort()
    yield chain, port, PacketHandler(2.0)
    port.closePort()


def test_ping_answers_model_1020(bus):
    chain, port, ph = bus
    model, result, error = ph.ping(port, 5)
    assert (model, result, error) == (ct.MODEL_NUMBER_XM430_W350, COMM_SUCCESS, 0)
    firmware, result, _ = ph.read1ByteTxRx(port, 5, ct.ADDR_FIRMWARE_VERSION)
    assert result == COMM_SUCCESS and firmware == 46


def test_ping_of_a_missing_id_times_out(bus):
    _, port, ph = bus
    _, result, _ = ph.ping(port, 40)
    assert result == COMM_RX_TIMEOUT


def test_broadcast_ping_lists_every_servo(bus):
    _, port, ph = bus
    found, result = ph.broadcastPing(port)
    assert result == COMM_SUCCESS
    assert sorted(found) == list(IDS)
    assert all(model == 1020 for model, _ in found.values())


def test_read_and_write_items(bus):
    chain, port, ph = bus
    assert ph.write1ByteTxRx(port, 3, ct.ADDR_LED, 1) == (COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 3, ct.ADDR_LED) == (1, COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 3, ct.ADDR_PROFILE_VELOCITY, 77) == (COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 3, ct.ADDR_PROFILE_VELOCITY) == (77, COMM_SUCCESS, 0)
    assert ph.read2ByteTxRx(port, 3, ct.ADDR_PRESENT_INPUT_VOLTAGE)[0] == 120
    assert chain.register(3, "LED") == 1


def test_write_errors_follow_the_control_table_rules(bus):
    _, port, ph = bus
    assert ph.write1ByteTxRx(port, 2, ct.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
    # EEPROM (address < 64) is locked while torque is on.
    assert ph.write1ByteTxRx(port, 2, ct.ADDR_RETURN_DELAY_TIME, 0) == (COMM_SUCCESS, ACCESS)
    # Read-only item.
    assert ph.write2ByteTxRx(port, 2, ct.ADDR_MODEL_NUMBER, 1) == (COMM_SUCCESS, ACCESS)
    # Half of a 4-byte item.
    assert ph.write2ByteTxRx(port, 2, ct.ADDR_GOAL_POSITION, 100) == (COMM_SUCCESS, DATA_LENGTH)
    # Beyond the range of an item, and beyond the Min/Max Position Limit.
    assert ph.write1ByteTxRx(port, 2, ct.ADDR_LED, 2) == (COMM_SUCCESS, DATA_RANGE)
    assert ph.write1ByteTxRx(port, 3, ct.ADDR_TORQUE_ENABLE, 0) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 3, ct.ADDR_MAX_POSITION_LIMIT, 3000) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 3, ct.ADDR_GOAL_POSITION, 3500) == (COMM_SUCCESS, DATA_LIMIT)
    # Reading past the end of the table.
    assert ph.readTxRx(port, 2, 140, 20)[1:] == (COMM_SUCCESS, DATA_RANGE)
    # With torque off again the EEPROM write goes through.
    assert ph.write1ByteTxRx(port, 2, ct.ADDR_TORQUE_ENABLE, 0) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 2, ct.ADDR_RETURN_DELAY_TIME, 0) == (COMM_SUCCESS, 0)


def test_sync_write_then_sync_read_moves_every_servo(bus):
    chain, port, ph = bus
    writer = GroupSyncWrite(port, ph, ct.ADDR_GOAL_POSITION, 4)
    for k, sid in enumerate(IDS):
        assert ph.write1ByteTxRx(port, sid, ct.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
        writer.addParam(sid, list((2048 + 50 * k).to_bytes(4, "little")))
    assert writer.txPacket() == COMM_SUCCESS
    assert chain.count(wire.SYNC_WRITE) == 1
    reader = GroupSyncRead(port, ph, ct.STATE_BLOCK_ADDRESS, ct.STATE_BLOCK_SIZE)
    for sid in IDS:
        reader.addParam(sid)
    deadline = time.monotonic() + 5.0
    while True:
        assert reader.txRxPacket() == COMM_SUCCESS
        positions = [reader.getData(sid, ct.ADDR_PRESENT_POSITION, 4) for sid in IDS]
        if all(abs(p - (2048 + 50 * k)) <= 2 for k, p in enumerate(positions)) or time.monotonic() > deadline:
            break
    assert [abs(p - (2048 + 50 * k)) <= 2 for k, p in enumerate(positions)] == [True] * len(IDS)
    assert chain.count(wire.SYNC_READ) >= 1


def test_bulk_write_and_bulk_read(bus):
    chain, port, ph = bus
    writer = GroupBulkWrite(port, ph)
    writer.addParam(4, ct.ADDR_LED, 1, [1])
    writer.addParam(9, ct.ADDR_PROFILE_VELOCITY, 4, list((123).to_bytes(4, "little")))
    assert writer.txPacket() == COMM_SUCCESS
    reader = GroupBulkRead(port, ph)
    reader.addParam(4, ct.ADDR_LED, 1)
    reader.addParam(9, ct.ADDR_PROFILE_VELOCITY, 4)
    assert reader.txRxPacket() == COMM_SUCCESS
    assert reader.getData(4, ct.ADDR_LED, 1) == 1
    assert reader.getData(9, ct.ADDR_PROFILE_VELOCITY, 4) == 123


def test_reg_write_waits_for_action(bus):
    chain, port, ph = bus
    assert ph.regWriteTxRx(port, 6, ct.ADDR_LED, 1, [1]) == (COMM_SUCCESS, 0)
    assert chain.register(6, "LED") == 0
    assert chain.register(6, "Registered Instruction") == 1
    assert ph.action(port, 254) == COMM_SUCCESS
    assert ph.read1ByteTxRx(port, 6, ct.ADDR_LED) == (1, COMM_SUCCESS, 0)


def test_corrupt_reply_surfaces_as_sdk_rx_corrupt(bus):
    chain, port, ph = bus
    chain.corrupt_next_replies(1, servo_id=8)
    _, result, _ = ph.ping(port, 8)
    assert result == COMM_RX_CORRUPT
    assert ph.ping(port, 8)[1] == COMM_SUCCESS


def test_host_packet_with_bad_crc_gets_crc_error_status(bus):
    chain, port, ph = bus
    packet = bytearray(wire.build_packet(5, wire.READ, bytes([ct.ADDR_LED, 0, 1, 0])))
    packet[-1] ^= 0xFF
    port.clearPort()
    port.writePort(packet)
    port.setPacketTimeout(11)
    reply, result = ph.rxPacket(port, False)
    assert result == COMM_SUCCESS
    assert reply[4] == 5 and reply[8] == CRC
    assert chain.crc_errors_from_host == 1


def test_overload_sets_alert_bit_and_torque_off_until_reboot(bus):
    chain, port, ph = bus
    assert ph.write1ByteTxRx(port, 4, ct.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
    chain.inject_overload(4)
    status, result, error = ph.read1ByteTxRx(port, 4, ct.ADDR_HARDWARE_ERROR_STATUS)
    assert result == COMM_SUCCESS and error & ct.ERROR_ALERT_BIT
    assert ct.hardware_error_names(status) == ("overload",)
    assert ph.read1ByteTxRx(port, 4, ct.ADDR_TORQUE_ENABLE)[0] == 0
    # Torque cannot come back while the error stands.
    assert ph.write1ByteTxRx(port, 4, ct.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, ct.ERROR_ALERT_BIT | RESULT_FAIL)
    assert ph.reboot(port, 4) == (COMM_SUCCESS, ct.ERROR_ALERT_BIT)
    wait_for_ping(port, ph, 4)
    assert ph.read1ByteTxRx(port, 4, ct.ADDR_HARDWARE_ERROR_STATUS) == (0, COMM_SUCCESS, 0)


def test_sustained_load_beyond_stall_trips_overload(bus):
    chain, port, ph = bus
    assert ph.write1ByteTxRx(port, 10, ct.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
    chain.set_load(10, 1.0)
    current, result, _ = ph.read2ByteTxRx(port, 10, ct.ADDR_PRESENT_CURRENT)
    assert result == COMM_SUCCESS
    assert abs(ct.to_signed(current, 2) * ct.CURRENT_MA_PER_LSB - 1.0 / 1.78 * 1000) < 20
    chain.set_load(10, 5.0)
    deadline = time.monotonic() + 2.0  # 1 s of simulated overload is 50 ms at speed 20
    while not chain.register(10, "Hardware Error Status") and time.monotonic() < deadline:
        pass
    assert chain.register(10, "Hardware Error Status") == 1 << ct.OVERLOAD_BIT
    assert chain.register(10, "Torque Enable") == 0


def test_status_return_level_zero_answers_only_ping(bus):
    _, port, ph = bus
    assert ph.write1ByteTxRx(port, 11, ct.ADDR_STATUS_RETURN_LEVEL, 0) == (COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 11, ct.ADDR_LED)[1] == COMM_RX_TIMEOUT
    assert ph.ping(port, 11)[1] == COMM_SUCCESS


def test_no_reply_fault(bus):
    chain, port, ph = bus
    chain.set_no_reply(7)
    assert ph.ping(port, 7)[1] == COMM_RX_TIMEOUT
    chain.set_no_reply(7, False)
    assert ph.ping(port, 7)[1] == COMM_SUCCESS


def test_pulled_cable_raises_serial_exception(bus):
    chain, port, ph = bus
    chain.disconnect()
    with pytest.raises(serial.SerialException):
        ph.ping(port, 1)
    port.is_using = False
    chain.reconnect()
    assert ph.ping(port, 1)[1] == COMM_SUCCESS


def test_servo_at_another_baud_rate_is_silent_until_the_host_matches(bus):
    chain, port, ph = bus
    assert ph.write1ByteTxRx(port, 12, ct.ADDR_BAUD_RATE, 1) == (COMM_SUCCESS, 0)  # 57600 bps
    assert ph.ping(port, 12)[1] == COMM_RX_TIMEOUT
    assert port.setBaudRate(57_600)
    assert ph.ping(port, 12)[:2] == (1020, COMM_SUCCESS)
    assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT


def test_reply_timing_follows_baud_rate_and_return_delay():
    """A 12-servo sync read takes 12 × (return delay + reply bytes), on the simulated clock."""
    clock = SimClock(1.0)
    chain = VirtualChain(ids=IDS, baud=1_000_000, clock=clock, seed=1)
    request = wire.build_packet(254, wire.SYNC_READ, bytes([126, 0, 10, 0, *IDS]))
    chain.host_opened(1_000_000)
    t0 = 1000.0  # wall time; the chain only compares it with the read times below
    chain.host_write(request, t0)
    tx_s = len(request) * 10e-6
    reply_s = (11 + 10) * 10e-6
    per_servo_s = 500e-6 + reply_s
    assert chain.host_read(t0 + tx_s + 500e-6 - 1e-6) == b""  # the first servo is still in its return delay
    first = chain.host_read(t0 + tx_s + per_servo_s - 1e-6)
    assert len(first) == 20  # bytes arrive one by one
    first += chain.host_read(t0 + tx_s + per_servo_s + 1e-7)
    assert len(first) == 21
    rest = chain.host_read(t0 + tx_s + 12 * per_servo_s + 1e-6)
    assert len(rest) == 11 * 21
    out = wire.PacketParser().feed(first + rest)
    assert [p.servo_id for p in out] == list(IDS)


def test_hand_and_fault_methods_are_safe_while_the_wire_is_busy(bus):
    chain, port, ph = bus
    stop = threading.Event()
    poses = []

    def hand():
        k = 0
        while not stop.is_set():
            chain.set_limp_position(1, 2048 + k % 100)
            poses.append(chain.present_positions_rad()[0])
            chain.corrupt_next_replies(0)
            k += 1

    thread = threading.Thread(target=hand, name="test-hand")
    thread.start()
    try:
        reader = GroupSyncRead(port, ph, ct.STATE_BLOCK_ADDRESS, ct.STATE_BLOCK_SIZE)
        for sid in IDS:
            reader.addParam(sid)
        for _ in range(30):
            assert reader.txRxPacket() == COMM_SUCCESS
            assert 2048 <= reader.getData(1, ct.ADDR_PRESENT_POSITION, 4) < 2148
    finally:
        stop.set()
        thread.join()
    assert poses and all(0 <= p < 100 * ct.RAD_PER_TICK for p in poses)


def test_factory_reset_keeps_id_and_baud_with_option_2(bus):
    chain, port, ph = bus
    assert ph.write1ByteTxRx(port, 8, ct.ADDR_RETURN_DELAY_TIME, 0) == (COMM_SUCCESS, 0)
    assert ph.factoryReset(port, 8, 0x02) == (COMM_SUCCESS, 0)
    wait_for_ping(port, ph, 8)
    assert ph.read1ByteTxRx(port, 8, ct.ADDR_RETURN_DELAY_TIME) == (250, COMM_SUCCESS, 0)


def test_supply_and_heat_faults_set_their_bits(bus):
    chain, port, ph = bus
    assert ph.write1ByteTxRx(port, 2, ct.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
    chain.set_supply_voltage(8.0)
    voltage, result, error = ph.read2ByteTxRx(port, 2, ct.ADDR_PRESENT_INPUT_VOLTAGE)
    assert (voltage, result) == (80, COMM_SUCCESS) and error & ct.ERROR_ALERT_BIT
    assert ct.hardware_error_names(chain.register(2, "Hardware Error Status")) == ("input voltage error",)
    assert chain.register(2, "Torque Enable") == 1  # the default Shutdown mask leaves voltage errors out
    chain.set_temperature(3, 85.0)
    assert ph.read1ByteTxRx(port, 3, ct.ADDR_PRESENT_TEMPERATURE)[0] == 85
    assert "overheating" in ct.hardware_error_names(chain.register(3, "Hardware Error Status"))
