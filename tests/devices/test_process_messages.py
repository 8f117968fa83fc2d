"""devices/process_messages.py: one typed message per kind, checked on receipt (kind, version, request id), and
exceptions that cross as the project's own classes. No processes, no Qt."""

from __future__ import annotations

import dataclasses
import pickle

import pytest

from devices import process_messages as messages
from devices.errors import DeviceError, NoReplyError, ServoCommandError


def test_a_message_of_another_kind_or_version_is_refused_naming_both():
    tick = messages.Tick((), True, "gait", False, 3, None, "SCHED_FIFO", 1.0)
    assert messages.expect(pickle.loads(pickle.dumps(tick)), messages.Tick) == tick
    with pytest.raises(messages.ProtocolError, match="expected Result or Event, got Tick"):
        messages.expect(tick, messages.Result, messages.Event)
    old = dataclasses.replace(tick, version=messages.VERSION + 1)
    with pytest.raises(messages.ProtocolError, match=f"protocol version {messages.VERSION + 1}; this side speaks"):
        messages.expect(old, messages.Tick)
    with pytest.raises(messages.ProtocolError, match="not a protocol message"):
        messages.expect(("tick", (), True), messages.Tick)  # the old positional tuples


def test_a_reply_is_matched_to_its_request():
    answer = messages.Result(7, 42)
    assert messages.reply_for(answer, 7).value == 42
    with pytest.raises(messages.ProtocolError, match="answer to request 7 came where 8's was awaited"):
        messages.reply_for(answer, 8)


def test_messages_are_immutable_and_every_field_is_named():
    call = messages.Call(1, "board.unplug")
    with pytest.raises(dataclasses.FrozenInstanceError):
        call.name = "other"  # type: ignore[misc]
    assert [f.name for f in dataclasses.fields(messages.Call)] == ["version", "request_id", "name", "args", "kwargs"]
    with pytest.raises(TypeError):
        messages.LabReady({"robot": "/dev/pts/1"}, 0.0)  # a field left out fails where it is built, not at the reader


@pytest.mark.parametrize("exc", [NoReplyError(4, "ping"), ServoCommandError(3, 7, "writing Goal Position"),
                                 ValueError("bad"), KeyError("x")])
def test_an_exception_crosses_as_its_own_class_with_its_message_and_attributes(exc):
    payload = pickle.loads(pickle.dumps(messages.ErrorPayload.of(exc, "robot")))
    rebuilt = payload.rebuild()
    assert type(rebuilt) is type(exc) and str(rebuilt) == str(exc) and payload.device == "robot"
    assert vars(rebuilt) == vars(exc)  # servo_id and the like


def test_a_class_the_other_side_cannot_import_becomes_a_device_error_with_the_message():
    payload = messages.ErrorPayload(1, "no.such.module", "Gone", ("the servo went away",), {})
    rebuilt = payload.rebuild()
    assert type(rebuilt) is DeviceError and str(rebuilt) == "the servo went away"


def test_an_attribute_that_does_not_pickle_stays_behind_and_the_message_crosses():
    exc = RuntimeError("port lost")
    exc.handle = lambda: None  # type: ignore[attr-defined]
    payload = messages.ErrorPayload.of(exc)
    assert "handle" not in payload.state and str(payload.rebuild()) == "port lost"
