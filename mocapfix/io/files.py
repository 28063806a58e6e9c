"""Writing output files whole or not at all, and one writer per output at a time."""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from pathlib import Path

from mocapfix.core.clip import MotionFileError, shown


def atomic_write(path: Path, write) -> None:
    """write(binary file object) into a temporary file beside path, then rename it to path: a
    reader (or a crash) never sees half a file, and an existing file stays as it was if writing
    fails. Makes the folder when it does not exist yet (`fix --out-dir new/`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        # mkstemp makes the file 0600 (private): give it the mode open() would, 0666 less the umask
        os.chmod(tmp, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def publish(written: Path, path: Path, replace: bool) -> None:
    """Move the finished file `written` (beside path) to path. replace=False never overwrites: a
    hard link claims the name atomically (FileExistsError if something else took it meanwhile),
    so a file that appeared while we worked is kept; on file systems without hard links, an
    exclusive create claims it and the rename fills it."""
    written, path = Path(written), Path(path)
    if replace:
        os.replace(written, path)
        return
    try:
        os.link(written, path)
    except FileExistsError:
        written.unlink(missing_ok=True)
        raise
    except OSError as e:
        if e.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK):
            raise
        os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY))  # FileExistsError if taken
        os.replace(written, path)
        return
    written.unlink()


@contextlib.contextmanager
def claimed(path: Path, source=None):
    """Hold the output `path` for one writer: an exclusive lock on `.<name>.lock` beside it, taken
    before the work and given up after the output is in place. A second writer (another
    `mocapfix fix` to the same -o) gets a MotionFileError at once instead of racing to the same
    rename. The operating system drops the lock when a process dies, so a killed run leaves no
    claim behind (at most the empty lock file, which the next run takes over)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = path.with_name(f".{path.name}.lock")
    while True:
        fd = os.open(lock, os.O_CREAT | os.O_RDWR, 0o666 & ~_umask())
        if not _try_lock(fd):
            os.close(fd)
            raise MotionFileError(
                source if source is not None else path,
                f"output {shown(path)} is being written by another run (lock {shown(lock.name)})",
            )
        try:  # the lock file we locked may have been removed by the run that held it: lock the new one
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        yield path
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()  # while still held: a waiting run re-checks the inode and makes a new one
        os.close(fd)  # releases the lock


def _try_lock(fd: int) -> bool:
    try:
        import fcntl
    except ImportError:  # Windows: a byte-range lock, also released when the process ends
        import msvcrt

        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    return True


def _umask() -> int:
    """The process's umask (os.umask can only be read by setting it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
