"""Writing output files whole or not at all, one writer per output at a time, and never through
a link: the folder an output goes to may hold names planted by someone else (a shared folder, an
unpacked archive), so what is opened there is opened without following links, and what is
created there is created exclusively."""

from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

from mocapfix.core.clip import MotionFileError, shown

# os.open flags: not following a link at the last component, and not hanging on a FIFO; 0 where
# the platform has no such flag (Windows: links are checked with lstat before, see _open_lock)
NO_FOLLOW = getattr(os, "O_NOFOLLOW", 0)
NON_BLOCKING = getattr(os, "O_NONBLOCK", 0)
CLOSE_ON_EXEC = getattr(os, "O_CLOEXEC", 0)


def atomic_write(path: Path, write) -> None:
    """write(binary file object) into a temporary file beside path, then rename it to path: a
    reader (or a crash) never sees half a file, and an existing file stays as it was if writing
    fails. Makes the folder when it does not exist yet (`fix --out-dir new/`). The temporary
    file is `.<name>.<random>.tmp`, created exclusively (never an existing name, never through a
    link); the rename replaces a link at path, it never writes through one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        # mkstemp makes the file 0600 (private): give it the mode open() would, 0666 less the umask
        if hasattr(os, "fchmod"):
            os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def temp_beside(path: Path) -> Path:
    """A new empty file `.<name>.<random>.tmp<ext>` beside path, for a writer that picks its
    format by the name's extension (Pillow, ffmpeg, matplotlib). Created exclusively, 0666 less
    the umask; claimed() removes it if the process dies before it is published or removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=f".tmp{path.suffix}")
    try:
        if hasattr(os, "fchmod"):
            os.fchmod(fd, 0o666 & ~_umask())
    finally:
        os.close(fd)
    return Path(tmp)


def publish(written: Path, path: Path, replace: bool) -> None:
    """Move the finished file `written` (beside path) to path. replace=False never overwrites: a
    hard link claims the name atomically (FileExistsError if something else took it meanwhile,
    a dangling link included), so a file that appeared while we worked is kept; on file systems
    without hard links, an exclusive create claims it and the rename fills it. replace=True
    replaces whatever entry is at path (a link itself, never the file it points to)."""
    written, path = Path(written), Path(path)
    if replace:
        os.replace(written, path)
        return
    try:
        os.link(written, path, follow_symlinks=False)
    except FileExistsError:
        written.unlink(missing_ok=True)
        raise
    except (OSError, NotImplementedError) as e:
        if isinstance(e, OSError) and e.errno not in (
            errno.EPERM,
            errno.ENOTSUP,
            errno.EOPNOTSUPP,
            errno.EXDEV,
            errno.EMLINK,
        ):
            raise
        # FileExistsError if taken (O_EXCL refuses a link there too, dangling or not)
        os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY | NO_FOLLOW | CLOSE_ON_EXEC, 0o666 & ~_umask()))
        os.replace(written, path)
        return
    written.unlink()


def check_output(path: Path, replace: bool, source=None) -> None:
    """MotionFileError (one line, naming `source` if given, else path) unless path is free to
    write: nothing there, or a regular file and replace. A link is refused whether or not it
    points anywhere: a run neither writes through it nor silently swaps it for a file; a folder
    or a FIFO is not an output either."""
    path = Path(path)
    who = source if source is not None else path
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    except OSError as e:
        raise MotionFileError(who, f"cannot use output {shown(path)} ({e.strerror or type(e).__name__})") from None
    if stat.S_ISLNK(st.st_mode):
        raise MotionFileError(
            who,
            f"output {shown(path)} is a symbolic link; not written through or replaced (remove it or name another)",
        )
    if stat.S_ISDIR(st.st_mode):
        raise MotionFileError(who, f"output {shown(path)} is a folder; name a file")
    if not stat.S_ISREG(st.st_mode):
        raise MotionFileError(who, f"output {shown(path)} is not a regular file")
    if not replace:
        raise MotionFileError(who, f"output {shown(path)} exists (use --force to overwrite)")


@contextlib.contextmanager
def writing(path: Path, source=None) -> Iterator[None]:
    """An OSError in the block (a full disk, a read-only folder) becomes one line naming the output
    path (and `source`, the input it was for): never a bare strerror that names a temporary file."""
    try:
        yield
    except OSError as e:
        why = e.strerror or " ".join(str(e).split()) or type(e).__name__
        if source is None:
            raise MotionFileError(path, f"cannot write this output ({why}); nothing was written") from None
        raise MotionFileError(source, f"cannot write output {shown(path)} ({why}); nothing was written") from None


@contextlib.contextmanager
def staged(paths: list[Path], replace: bool, source=None) -> Iterator[list[Path]]:
    """One temporary file beside each of paths (temp_beside), yielded in the same order, for the
    block to write; when the block ends without an error they are moved into place (publish)
    together: a file that appeared at one of paths meanwhile stops them all (MotionFileError),
    and the ones already moved are taken back (without replace they are new files of ours). The
    temporary files are gone afterwards, whatever happened."""
    paths = [Path(p) for p in paths]
    temps: list[Path] = []
    try:
        for p in paths:
            with writing(p, source):
                temps.append(temp_beside(p))
        yield temps
        done: list[Path] = []
        for tmp, p in zip(temps, paths):
            try:
                with writing(p, source):
                    publish(tmp, p, replace)
            except (FileExistsError, MotionFileError) as e:
                if not replace:
                    for q in done:
                        q.unlink(missing_ok=True)
                if isinstance(e, MotionFileError):
                    raise
                raise MotionFileError(
                    source if source is not None else p,
                    f"output {shown(p)} appeared while writing (another program?); kept, nothing written",
                ) from None
            done.append(p)
    finally:
        for tmp in temps:
            tmp.unlink(missing_ok=True)


@contextlib.contextmanager
def claimed(path: Path, source=None):
    """Hold the output `path` for one writer: an exclusive lock on `.<name>.lock` beside it, taken
    before the work and given up after the output is in place. A second writer (another
    `mocapfix fix` to the same -o) gets a MotionFileError at once instead of racing to the same
    rename. The operating system drops the lock when a process dies, so a killed run leaves no
    claim behind (at most the empty lock file, which the next run takes over); its temporary
    files are removed here, as holding the lock proves no live writer owns them. Only then: a
    writer makes its temporary files after the lock and removes them before it, so without a
    lock file left over there is nothing to look for (and a folder of 10,000 outputs is not
    listed 10,000 times). A lock that is a link, a folder or anything but a regular file is
    refused, never followed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = path.with_name(f".{path.name}.lock")
    who = source if source is not None else path
    while True:
        fd, left_over = _open_lock(lock, who)
        if not _try_lock(fd):
            os.close(fd)
            raise MotionFileError(
                who, f"output {shown(path)} is being written by another run (lock {shown(lock.name)})"
            )
        try:  # the lock file we locked may have been removed by the run that held it: lock the new one
            now, held = os.lstat(lock), os.fstat(fd)
            same = (now.st_dev, now.st_ino) == (held.st_dev, held.st_ino)
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        if left_over:
            remove_stale_temps(path)
        yield path
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()  # while still held: a waiting run re-checks the inode and makes a new one
        os.close(fd)  # releases the lock


def _open_lock(lock: Path, who) -> tuple[int, bool]:
    """The lock file's descriptor, created, or opened where one is there already (-> True: a run
    left it, or holds it), without following a link and without blocking on a FIFO;
    MotionFileError for anything but a regular file there."""
    refused = MotionFileError(
        who,
        f"lock {shown(lock)} is a symbolic link or not a regular file; not followed (remove it if no run is writing)",
    )
    if not NO_FOLLOW and os.path.islink(lock):  # no O_NOFOLLOW (Windows): look first
        raise refused
    flags = os.O_RDWR | NO_FOLLOW | NON_BLOCKING | CLOSE_ON_EXEC
    try:
        for _ in range(100):  # the lock file can go (its run ends) between the two opens: again
            try:
                fd, left_over = os.open(lock, flags | os.O_CREAT | os.O_EXCL, 0o666 & ~_umask()), False
                break
            except FileExistsError:
                pass
            with contextlib.suppress(FileNotFoundError):
                fd, left_over = os.open(lock, flags), True
                break
        else:
            raise OSError(errno.EAGAIN, "it keeps coming and going")
    except OSError as e:
        # ELOOP: a link (Linux, macOS); EMLINK / EFTYPE: the BSDs' words for it; EISDIR: a folder
        if e.errno in (errno.ELOOP, errno.EMLINK, errno.EISDIR, getattr(errno, "EFTYPE", -1), errno.ENXIO):
            raise refused from None
        raise MotionFileError(who, f"cannot open lock {shown(lock)} ({e.strerror or type(e).__name__})") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise refused
    return fd, left_over


def stale_temp_pattern(path: Path) -> re.Pattern:
    """The names of the temporary files a writer of `path` makes beside it: `.<name>.<r>.tmp`
    (atomic_write), `.<name>.<r>.tmp<ext>` (temp_beside), the atomic_write temporary of one of
    those (`..<name>.<r>.tmp<ext>.<r>.tmp`), and fix's staged files of earlier versions
    (`.<stem>.<pid>.partial<ext>`). The lock and any other hidden file do not match."""
    name, stem, ext = re.escape(path.name), re.escape(path.stem), re.escape(path.suffix)
    return re.compile(rf"\.\.?(?:{name}\.[^/]+\.tmp(?:{ext})?|{stem}\.\d+\.partial{ext}(?:\.[^/]+\.tmp)?)")


def remove_stale_temps(path: Path) -> list[Path]:
    """Remove the temporary files of output `path` a killed writer left beside it (only while
    holding its claim: then no live writer owns them); files and links only, never a folder.
    -> what was removed."""
    path = Path(path)
    pattern, removed = stale_temp_pattern(path), []
    try:
        names = os.listdir(path.parent)
    except OSError:
        return removed
    for name in names:
        if not pattern.fullmatch(name):
            continue
        p = path.parent / name
        with contextlib.suppress(OSError):
            if not stat.S_ISDIR(os.lstat(p).st_mode):
                p.unlink()
                removed.append(p)
    return removed


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
