"""Reading a TOML or JSON file a user names — a scene, a sweep, a gains file, a shape, a calibration — so that no file
can hang, exhaust or crash the reader: every refusal is one error that names the file and the cause.

- Only a regular file is read. A FIFO (whose open would wait for a writer), a device (``/dev/zero`` reads for ever),
  a socket or a folder is refused for what it is; the file is opened without blocking and checked on the open
  descriptor, so a link swapped in between changes nothing.
- At most :data:`MAX_TOML_BYTES` (1 MB; the largest scene or sweep file is a few kB) are read.
- UTF-8 text, valid TOML, nested no deeper than Python's parser goes (a 200 000-deep array is refused, not a
  ``RecursionError``), and every integer within ±2⁶³ (a 400-digit integer would overflow a float later; one of more
  than 4300 digits is refused by Python's parser itself): the key is named.
- JSON (:func:`read_json_file`): the same file checks, then valid JSON (its line named), nested no deeper than
  Python's parser goes, no integer of more than 4300 digits and, when asked, no key given twice in one object.

Pure Python; any thread.
"""

from __future__ import annotations

import errno
import json
import os
import stat
import sys
from pathlib import Path
from typing import Any

import tomllib

MAX_TOML_BYTES = 1_000_000
MAX_INTEGER = 2**63 - 1  # the largest integer a TOML reader must take (TOML 1.0: a signed 64-bit range)

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"))


def _kind(mode: int) -> str | None:
    if stat.S_ISREG(mode):
        return None
    return next((words for test, words in _KINDS if test(mode)), "not a regular file")


def read_toml_file(path: str | os.PathLike[str], what: str, error: type[Exception] = ValueError,
                   not_found: str = "") -> tuple[str, dict[str, Any]]:
    """(text, parsed table) of the TOML file ``path``, a ``what`` ("scene file", "sweep file", …): see the module
    docstring. Every refusal is ``error`` naming the file and the cause; ``not_found`` is added to the message for a
    missing file."""
    text = read_text_file(path, what, error, not_found)
    return text, parse_toml_text(text, str(path), what, error)


def read_text_file(path: str | os.PathLike[str], what: str, error: type[Exception] = ValueError,
                   not_found: str = "", max_bytes: int = MAX_TOML_BYTES) -> str:
    """The UTF-8 text of the regular file ``path`` (at most ``max_bytes``, :data:`MAX_TOML_BYTES` unless told);
    ``error`` otherwise. Any small text file a user names (a shape, a servo settings file) is read through here."""
    file = Path(path)
    try:
        fd = os.open(file, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise error(f"{file}: {what} not found{not_found}") from None
    except IsADirectoryError:
        raise error(f"{file}: is a folder, not a {what}") from None
    except OSError as exc:
        why = "a symbolic link loop (it leads back to itself)" if exc.errno == errno.ELOOP else exc.strerror
        raise error(f"{file}: cannot be read ({why})") from None
    try:
        kind = _kind(os.fstat(fd).st_mode)
        if kind is not None:
            raise error(f"{file}: is {kind}, not {_article(what)} {what}: only a regular file is read")
        raw = _read_capped(fd, file, what, error, max_bytes)
    finally:
        os.close(fd)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{file}: not a UTF-8 text file (byte {exc.start} is not UTF-8: a binary file?)") from None


def read_json_file(path: str | os.PathLike[str], what: str, error: type[Exception] = ValueError,
                   max_bytes: int = MAX_TOML_BYTES, refuse_repeated_keys: bool = False, not_found: str = "") -> Any:
    """The parsed JSON file ``path``, a ``what`` ("shape file", "calibration file", …), read through
    :func:`read_text_file` (a regular file of at most ``max_bytes``) and :func:`parse_json_text`: every refusal is
    ``error`` naming the file and the cause."""
    return parse_json_text(read_text_file(path, what, error, not_found, max_bytes), str(path), what, error,
                           refuse_repeated_keys)


class _RepeatedKey(Exception):
    def __init__(self, key: str) -> None:
        super().__init__(key)
        self.key = key


def _refuse_repeated_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    result: dict[str, Any] = {}
    for key, value in pairs:
        if key in result:
            raise _RepeatedKey(key)
        result[key] = value
    return result


def parse_json_text(text: str, source: str, what: str, error: type[Exception] = ValueError,
                    refuse_repeated_keys: bool = False) -> Any:
    """``text`` parsed as JSON; ``error`` naming ``source`` for invalid JSON (with its line), nesting too deep for
    the parser, an integer of more digits than Python converts, or — with ``refuse_repeated_keys`` — a key given
    twice in one object (json keeps the last one silently, so such a file is ambiguous)."""
    hook = _refuse_repeated_keys if refuse_repeated_keys else None
    try:
        return json.loads(text, object_pairs_hook=hook)
    except _RepeatedKey as repeated:
        raise error(f"{source}: {repeated.key!r} is given twice in one object (JSON keeps only the last: the file "
                    "is ambiguous)") from None
    except json.JSONDecodeError as exc:
        raise error(f"{source}:{exc.lineno}: not valid JSON ({exc.msg}): not {_article(what)} {what}") from None
    except RecursionError:
        raise error(f"{source}: nested too deeply to be {_article(what)} {what}") from None
    except ValueError:  # Python's own limit on an integer's digits (4300): its words name no file
        raise error(f"{source}: holds an integer of more than {sys.get_int_max_str_digits()} digits: not "
                    f"{_article(what)} {what}") from None


def _article(noun: str) -> str:
    return "an" if noun[:1].lower() in "aeiou" else "a"


def parse_toml_text(text: str, source: str, what: str, error: type[Exception] = ValueError) -> dict[str, Any]:
    """``text`` parsed as TOML; ``error`` naming ``source`` for invalid TOML, nesting too deep for the parser or an
    integer beyond ±:data:`MAX_INTEGER` (its key named)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{source}: not valid TOML: {exc}") from None
    except RecursionError:
        raise error(f"{source}: nested too deeply to be a {what}") from None
    except ValueError:  # Python's own limit on an integer's digits (4300): the parser's words name no line
        raise error(f"{source}: holds an integer of more than {sys.get_int_max_str_digits()} digits: no key of a "
                    f"{what} takes such a number") from None
    _check_integers(data, source, error)
    return data


def _read_capped(fd: int, file: Path, what: str, error: type[Exception], max_bytes: int = MAX_TOML_BYTES) -> bytes:
    chunks: list[bytes] = []
    size = 0
    while chunk := os.read(fd, 1 << 16):
        size += len(chunk)
        if size > max_bytes:
            raise error(f"{file}: larger than {max_bytes / 1e6:g} MB, too large for {_article(what)} {what}")
        chunks.append(chunk)
    return b"".join(chunks)


def _check_integers(data: dict[str, Any], source: str, error: type[Exception]) -> None:
    """Refuse an integer beyond ±:data:`MAX_INTEGER`, naming its key (walked without recursion)."""
    stack: list[tuple[str, Any]] = [("", data)]
    while stack:
        where, value = stack.pop()
        if isinstance(value, dict):
            stack.extend((f"{where}.{key}" if where else str(key), item) for key, item in value.items())
        elif isinstance(value, list):
            stack.extend((f"{where}[{k}]", item) for k, item in enumerate(value))
        elif isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_INTEGER:
            raise error(f"{source}: '{where}' is a {len(str(abs(value)))}-digit integer, beyond what any key takes "
                        f"(at most ±{MAX_INTEGER:.3g})")


# A file a command keeps in its own folder (a series' state, a session's protocol, a batch): a few kB.
MAX_STATE_BYTES = 16_000_000


def read_state_file(path: str | os.PathLike[str], what: str, max_bytes: int = MAX_STATE_BYTES) -> str:
    """The UTF-8 text of a file a command keeps in its folder (``what``: "series file", …): FileNotFoundError when
    there is none (the command starts afresh), ValueError naming it when it is no regular file (a FIFO planted
    there would hang the read), too large or not UTF-8 (:func:`read_text_file`)."""
    if not os.path.lexists(path):
        raise FileNotFoundError(errno.ENOENT, f"{path}: no such file", str(path))
    return read_text_file(path, what, ValueError, max_bytes=max_bytes)
