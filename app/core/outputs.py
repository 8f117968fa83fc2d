"""Output files: the one rule every writer follows, and the hidden temporaries outputs are built in.

The rule: **an output only ever replaces a regular file.** A path that exists and is — or, through symbolic links,
leads to — a device (``/dev/null``), a FIFO, a socket or a folder is refused with one line saying what it is, before
anything is written and again just before the finished file is moved into place; a symbolic link loop is named as
one. (Writing *into* a device or a pipe cannot be all or nothing, and a rename would replace the device node itself:
as root, ``--out /dev/null`` used to turn /dev/null into a regular file.)

Every output is built in a hidden temporary beside it, created here and nowhere else: exclusively
(``O_CREAT | O_EXCL | O_NOFOLLOW``: never through a planted symbolic link, never someone else's file) under an
unpredictable name that carries the writer's pid (``.NAME.<pid>.<random>.partial``). It is moved onto the output only
when complete. A temporary left by a writer that was killed (``kill -9``, a power cut) is removed by the next writer
of the same output once it is provably stale: the pid in its name is no process on this machine. The writers:
:func:`app.core.calfiles.write_atomically` (CSV and JSON), :mod:`app.core.recording` (recordings, re-estimated and
repaired copies), :func:`app.core.shapes.write_shape`, :func:`write_new_file` (a file that must not replace one: a
servo settings backup, a saved event log, a new lab config), the lab config :mod:`app.core.servo_settings`
rewrites, ``sensnake play --log``, and :func:`replacing_text` / :func:`replace_text` for the files a
sweep, a tuning study or an evaluation writes into its folder.

Any thread; no state.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import secrets
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import TextIO

from app.core.errors import OutputPathError

NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
TEMPORARY_SUFFIXES = (".partial", ".tmp", ".partial.c3d")  # .c3d: ezc3d insists on it (app.core.mocap)
_CREATE_ATTEMPTS = 100


def describe_kind(mode: int) -> str | None:
    """What a file of ``mode`` is in a user's words, or None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    for test, words in ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
                        (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                        (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return words
    return "not a regular file"


def check_output(path: str | os.PathLike[str]) -> Path:
    """``path`` as a :class:`Path` if a writer may create or replace it; :class:`OutputPathError` naming it and the
    cause otherwise (a device, FIFO, socket or folder there or at the end of its symbolic links; a link loop).
    A missing path, or a dangling link, is fine here: the folder it would go into is the writer's to check."""
    out = Path(path)
    try:
        status = os.stat(out)
    except FileNotFoundError:
        return out
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OutputPathError(f"{out} is a symbolic link loop (it leads back to itself): remove it or choose "
                                  "another name") from None
        return out  # ENOTDIR, EACCES, …: the writer's own attempt names the cause
    kind = describe_kind(status.st_mode)
    if kind is None:
        return out
    what = f"a symbolic link to {os.path.realpath(out)}, {kind}" if os.path.islink(out) else kind
    if kind == "a folder":
        raise OutputPathError(f"{out} is {what}: give a file name to write")
    raise OutputPathError(f"{out} is {what}, not a regular file: outputs only ever replace regular files, choose a "
                          "file name")


def _host_pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # it exists (another user's): not ours to judge
    return True


# A file name may be 255 bytes long; its temporary adds a dot, a pid, 8 hex digits and a suffix (~35 bytes). A name
# that leaves no room for them is shortened in its temporary's name to this many bytes plus a hash of the whole.
_TEMPORARY_NAME_BYTES = 180


def temporary_stem(name: str) -> str:
    """``name`` as it appears in its temporaries' names: itself, or (when too long to leave room for the rest) its
    first bytes and a hash of the whole, so a legal 255-byte name can still be written."""
    raw = name.encode("utf-8", "surrogateescape")
    if len(raw) <= _TEMPORARY_NAME_BYTES:
        return name
    head = raw[:_TEMPORARY_NAME_BYTES].decode("utf-8", "ignore")
    return f"{head}~{hashlib.sha1(raw).hexdigest()[:8]}"


def _temporary_pattern(name: str) -> re.Pattern[str]:
    suffixes = "|".join(re.escape(s) for s in TEMPORARY_SUFFIXES)
    return re.compile(rf"^\.{re.escape(temporary_stem(name))}\.(\d+)\.[0-9a-f]+(?:{suffixes})$")


def remove_stale_temporaries(out: str | os.PathLike[str]) -> list[Path]:
    """Remove the hidden temporaries of ``out`` that a killed writer left (``.NAME.<pid>.<random>.partial|.tmp``
    whose pid is no running process here); returns what was removed. Only regular files are touched."""
    out = Path(out)
    folder = out.parent if str(out.parent) else Path(".")
    pattern = _temporary_pattern(out.name)
    removed: list[Path] = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        match = pattern.match(entry.name)
        if match is None or _host_pid_alive(int(match.group(1))):
            continue
        with contextlib.suppress(OSError):
            if entry.is_file(follow_symlinks=False):
                os.unlink(entry.path)
                removed.append(Path(entry.path))
    return removed


def create_temporary(out: str | os.PathLike[str], suffix: str = ".partial", mode: int = 0o666) -> tuple[int, Path]:
    """Create the hidden temporary for ``out`` (see the module docstring) and return (its open descriptor for
    writing, its path). ``mode`` less the umask is its permission (the kernel applies the umask). Stale
    temporaries of ``out`` are removed first. OSError when the folder cannot take it."""
    out = Path(out)
    folder = out.parent if str(out.parent) else Path(".")
    remove_stale_temporaries(out)
    for _attempt in range(_CREATE_ATTEMPTS):
        work = folder / f".{temporary_stem(out.name)}.{os.getpid()}.{secrets.token_hex(4)}{suffix}"
        try:
            fd = os.open(work, os.O_WRONLY | os.O_CREAT | os.O_EXCL | NOFOLLOW | getattr(os, "O_BINARY", 0), mode)
        except FileExistsError:
            continue
        return fd, work
    raise FileExistsError(errno.EEXIST, f"no free temporary name for {out.name} in {folder}")


def keep_mode(out: Path, work: Path) -> None:
    """A file that replaces ``out`` keeps ``out``'s permissions (a new one has the umask's)."""
    with contextlib.suppress(FileNotFoundError):
        os.chmod(work, stat.S_IMODE(out.stat().st_mode))


def move_into_place(work: Path, out: Path) -> None:
    """Replace ``out`` by the finished ``work`` (same folder), keeping ``out``'s mode; the output rule is checked
    again here, at the last moment (a FIFO made at ``out`` while the work ran is refused, never replaced)."""
    check_output(out)
    keep_mode(out, work)
    os.replace(work, out)


@contextlib.contextmanager
def temporary_beside(out: str | os.PathLike[str], suffix: str = ".partial") -> Iterator[tuple[int, Path]]:
    """A hidden temporary for ``out`` (descriptor, path) that is removed when the block fails; the caller moves it
    into place (:func:`move_into_place`) before the block ends. The output rule is checked first."""
    target = check_output(out)
    fd, work = create_temporary(target, suffix)
    try:
        yield fd, work
    except BaseException:
        with contextlib.suppress(OSError):
            work.unlink()
        raise


@contextlib.contextmanager
def replacing_text(out: str | os.PathLike[str], newline: str = "") -> Iterator[TextIO]:
    """A UTF-8 text handle onto a hidden temporary for ``out``, moved onto ``out`` when the block ends without error
    and removed when it fails: ``with replacing_text(path) as f:`` in place of ``with open(path, "w") as f:`` for a
    file inside a folder a command fills (a sweep's summary, a study's trials), so a FIFO or link planted at its
    name is never opened or written through."""
    target = check_output(out)
    fd, work = create_temporary(target, ".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline=newline) as handle:
            yield handle
        move_into_place(work, target)
    except BaseException:
        with contextlib.suppress(OSError):
            work.unlink()
        raise


def replace_text(out: str | os.PathLike[str], text: str) -> None:
    """``text`` as the whole UTF-8 file ``out`` (:func:`replacing_text`)."""
    with replacing_text(out, newline="\n") as handle:
        handle.write(text)


HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def _run_uid(path: Path) -> str | None:
    """The ``run_start`` uid of the HDF5 file at ``path`` (None: none, or unreadable)."""
    from app.core.run_documents import read_documents  # here: outputs is imported where h5py is not wanted

    try:
        start, _ = read_documents(path)
    except (OSError, ValueError, KeyError, TypeError, RuntimeError):  # unreadable: no run to name
        return None
    uid = start.get("uid") if start else None
    return str(uid) if uid else None


def refuse_replacing_a_recording(out: str | os.PathLike[str],
                                 same_run_as: tuple[str | os.PathLike[str], ...] = ()) -> None:
    """:class:`OutputPathError` when ``out`` is an HDF5 file (a recording holds raw data nothing else does) that is
    not a copy of the same run as one of ``same_run_as`` (an estimate or repair of a recording may replace its own
    earlier copy). A CSV, a JSON or a figure written over a recording, or a run over another run, lost it."""
    target = Path(out)
    try:
        with open(target, "rb") as f:
            head = f.read(len(HDF5_SIGNATURE))
    except OSError:
        return  # missing, or not a regular file: the other checks name it
    if head != HDF5_SIGNATURE:
        return
    uid = _run_uid(target)
    if uid is not None and any(_run_uid(Path(p)) == uid for p in same_run_as if os.path.isfile(p)):
        return
    what = f"a recording (run {uid})" if uid else "an HDF5 file (a recording?)"
    raise OutputPathError(f"{out} is {what}: an output never replaces a recording; choose another name, or move it "
                          "away first")


def check_new_file(out: str | os.PathLike[str], why: str) -> None:
    """OSError naming ``out`` when a new file cannot go there: something is at ``out`` (a file, a symbolic link, a
    device, …: FileExistsError; ``why`` says why an existing file is kept) or its folder is missing
    (FileNotFoundError)."""
    out = Path(out)
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        raise FileNotFoundError(errno.ENOENT, f"cannot write {out}: the folder {folder} {what}")
    try:
        info = os.lstat(out)
    except FileNotFoundError:
        return
    kind = None if stat.S_ISLNK(info.st_mode) else describe_kind(info.st_mode)
    if kind is not None:
        raise FileExistsError(errno.EEXIST, f"{out} is {kind}, not a file to write: nothing written")
    raise FileExistsError(errno.EEXIST, f"{out} exists: {why}")


def write_new_file(out: str | os.PathLike[str], data: bytes, why: str) -> Path:
    """``data`` as a NEW file at ``out``, whole or not at all: built in a hidden temporary and linked into place, a
    link that fails if anything appeared at ``out`` meanwhile, so an existing file is never replaced
    (FileExistsError naming it, ``why`` saying why it is kept; :func:`check_new_file`). Any other failure is an
    OSError naming ``out``, never the temporary, and leaves nothing behind."""
    out = Path(out)
    check_new_file(out, why)
    try:
        fd, work = create_temporary(out, ".tmp")
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write {out}: {exc.strerror or exc}") from None
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        try:
            os.link(work, out)
        except FileExistsError:
            raise FileExistsError(errno.EEXIST, f"{out} exists: {why}") from None
        except OSError as exc:
            if exc.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EXDEV):
                raise
            check_new_file(out, why)  # a file system without hard links (FAT, some shares): the check, then a move
            os.replace(work, out)
    except FileExistsError:
        raise
    except OSError as exc:  # a full disk, a quota: the user's path in the message
        raise OSError(exc.errno, f"cannot write {out}: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(work)
    return out


def open_lock_file(path: Path) -> int:
    """A descriptor on the lock file ``path`` (created when missing), which must be a regular file of its own: a
    symbolic link planted there is not followed (the lock's pid would be written over the file it leads to), a
    FIFO or device is not opened for blocking. :class:`OutputPathError` names it otherwise."""
    flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
    try:
        fd = os.open(path, flags, 0o644)
    except OSError as exc:
        if os.path.islink(path):
            raise OutputPathError(f"{path} (the lock file) is a symbolic link: a lock file must be a file of its own; "
                                  "remove it and run again") from None
        raise OSError(exc.errno, f"cannot create the lock file {path}: {exc.strerror or exc}") from None
    kind = describe_kind(os.fstat(fd).st_mode)
    if kind is not None:
        os.close(fd)
        raise OutputPathError(f"{path} (the lock file) is {kind}, not a regular file: remove it and run again")
    os.set_blocking(fd, True)
    return fd
