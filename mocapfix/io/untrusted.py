"""Opening the files a user names, as untrusted input: regular files only, read no further than
their size, and messages that never carry their contents.

A name can stand for something that is not a file: a FIFO (opening it waits for a writer that
never comes), a device (/dev/zero reads forever), a folder. Every reader opens through
open_regular, which refuses those before a byte is read. Links are followed: a link to a
regular file is that file.
"""

from __future__ import annotations

import json
import os
import stat
from typing import BinaryIO

from mocapfix.core.clip import MotionFileError

# The most text read at once: about 50 minutes of a 100-joint BVH at 120 fps (300 channels of
# ~10 characters a frame). Parsing takes several times the text in memory, so a larger file is
# refused in one line rather than run the machine out of memory (split a longer take).
MAX_TEXT_BYTES = 1 << 30

_NOT_REGULAR = (
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISDIR, "a folder"),
)


def open_regular(path, what: str = "file") -> BinaryIO:
    """path opened for binary reading, or a MotionFileError naming it: missing, unreadable, or
    not a regular file (a FIFO, a device, a socket, a folder). The open never blocks: O_NONBLOCK
    makes opening a FIFO return at once, and fstat of the open file (not of the name, which could
    change in between) decides. what: the kind of file, for messages ("joint map")."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise MotionFileError(path, f"{what} not found") from None
    except OSError as e:  # no permission, a socket (ENXIO), a name too long, ...
        raise MotionFileError(path, f"cannot read this {what} ({e.strerror or type(e).__name__})") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = next((name for is_kind, name in _NOT_REGULAR if is_kind(mode)), "a special file")
            raise MotionFileError(path, f"not a regular file ({kind}); give a {what} on disk")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)  # a regular file: back to the plain mode every reader expects
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def file_size(f: BinaryIO) -> int:
    """Bytes in the open file f, as fstat says now."""
    return os.fstat(f.fileno()).st_size


def read_bytes(path, what: str = "file", limit: int = MAX_TEXT_BYTES) -> bytes:
    """The whole of a regular file (open_regular), at most its size when opened and at most
    `limit` bytes (a larger file is a MotionFileError, before reading)."""
    with open_regular(path, what) as f:
        size = file_size(f)
        check_size(path, size, what, limit)
        return f.read(size)


def read_text_lines(path, what: str) -> tuple[list[str], str]:
    """A text file a writer puts back line by line -> (its lines, its newline: "\r\n" or "\n");
    unreadable or not UTF-8: the file's one-line error."""
    try:
        text = read_bytes(path, what).decode("utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise MotionFileError(path, f"cannot read as text ({type(e).__name__})") from None
    return text.splitlines(), "\r\n" if "\r\n" in text else "\n"


def read_json(path, what: str):
    """A JSON file's document; unreadable, not UTF-8 or not JSON: the file's one-line error."""
    try:
        return json.loads(read_bytes(path, what).decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
        raise MotionFileError(path, f"not readable JSON ({type(e).__name__})") from None


def check_size(path, size: int, what: str, limit: int = MAX_TEXT_BYTES) -> None:
    if size > limit:
        raise MotionFileError(
            path,
            f"{what} of {size / 2**20:.0f} MiB, more than mocapfix reads at once ({limit / 2**20:.0f} MiB)",
        )


def quoted(text, limit: int = 40) -> str:
    """A piece of a file (a joint name, a column header) as a message may show it: quoted, with
    control characters escaped (no terminal escape codes reach the user's terminal) and at most
    about `limit` characters, so that a message stays one short line whatever the file holds."""
    text = str(text)
    short = text if len(text) <= limit else text[:limit] + "..."
    return repr(short)  # repr escapes every non-printable character, \x1b included


def printable(text, limit: int = 160) -> str:
    """Text from elsewhere (a library's error message, which may quote the file) on one short
    line: whitespace runs as one space, non-printable characters escaped, at most `limit`
    characters."""
    text = " ".join(str(text).split())
    text = text if text.isprintable() else ascii(text)[1:-1]
    return text if len(text) <= limit else text[:limit] + "..."
