"""A minimal XDF 1.0 writer for tests (LabRecorder's format: github.com/sccn/xdf): a file header, one stream header,
its samples with their time stamps, and its footer, per stream."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np


def _chunk(tag: int, content: bytes) -> bytes:
    return struct.pack("<BQH", 8, len(content) + 2, tag) + content


def stream_xml(name: str, kind: str, channels: Sequence[dict[str, str]], rate_hz: float) -> str:
    described = "".join("<channel>" + "".join(f"<{k}>{escape(v)}</{k}>" for k, v in ch.items()) + "</channel>"
                        for ch in channels)
    return (f"<?xml version=\"1.0\"?><info><name>{escape(name)}</name><type>{escape(kind)}</type>"
            f"<channel_count>{len(channels)}</channel_count><nominal_srate>{rate_hz}</nominal_srate>"
            f"<channel_format>double64</channel_format><source_id>{escape(name)}</source_id>"
            f"<desc><channels>{described}</channels></desc></info>")


def write_xdf(path: Path, streams: Sequence[tuple[str, np.ndarray, np.ndarray]]) -> Path:
    """``streams``: (header XML, time stamps (N,), values (N, C)) each."""
    out = bytearray(b"XDF:")
    out += _chunk(1, b"<?xml version=\"1.0\"?><info><version>1.0</version></info>")
    for sid, (xml, _, _) in enumerate(streams, start=1):
        out += _chunk(2, struct.pack("<I", sid) + xml.encode())
    for sid, (_, stamps, values) in enumerate(streams, start=1):
        body = bytearray(struct.pack("<I", sid))
        body += struct.pack("<BQ", 8, len(stamps))
        for t, row in zip(stamps, np.asarray(values, dtype=np.float64)):
            body += struct.pack("<Bd", 8, float(t)) + row.tobytes()
        out += _chunk(3, bytes(body))
    for sid, (_, stamps, _) in enumerate(streams, start=1):
        footer = (f"<?xml version=\"1.0\"?><info><first_timestamp>{stamps[0]}</first_timestamp><last_timestamp>"
                  f"{stamps[-1]}</last_timestamp><sample_count>{len(stamps)}</sample_count></info>")
        out += _chunk(6, struct.pack("<I", sid) + footer.encode())
    path.write_bytes(bytes(out))
    return path
