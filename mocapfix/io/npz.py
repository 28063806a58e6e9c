"""Reading .npz archives as untrusted input: one MotionFileError for every way a file can be
broken, and no pickle ever run (restricted_pickle.py reads the object arrays public formats
store).

np.load(allow_pickle=True) would execute a pickled object's __reduce__: a shared motion file
could run any command. So archives are always opened with allow_pickle=False; an object array
(VideoPose3D's positions_3d dict, AMASS's pickled gender) is read from the member's raw bytes by
the restricted unpickler, which builds containers and numpy arrays and refuses everything else.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
from numpy.lib.npyio import NpzFile

from mocapfix.core.clip import MotionFileError
from mocapfix.io.restricted_pickle import RefusedPickle, load_arrays
from mocapfix.io.untrusted import open_regular, printable, quoted


def load_npz(path: Path, what: str = "npz file"):
    """An .npz archive (np.load's NpzFile, never unpickling), or a MotionFileError. Read from the
    file open_regular opened (a FIFO or a device is refused before a byte is read); a zip archive
    is read by seeking within the file's size."""
    path = Path(path)
    f = open_regular(path, what)
    try:
        magic = f.read(6)
        if magic.startswith(b"\x93NUMPY"):
            raise MotionFileError(
                path, "a single .npy array, not an .npz archive of named arrays (np.savez writes one)"
            )
        if not magic.startswith(b"PK"):  # else np.load tries pickle and blames allow_pickle
            raise MotionFileError(path, "not an npz file (an .npz is a zip archive of .npy arrays)")
        f.seek(0)
        # NpzFile owns f from here: closing the archive closes the file.
        return NpzFile(f, own_fid=True, allow_pickle=False)
    except MotionFileError:
        f.close()
        raise
    except Exception as e:  # BadZipFile, EOFError, OSError, ValueError ...
        f.close()
        raise MotionFileError(path, f"not a readable npz file ({one_line(e)})") from None


def deflated(data) -> bool:
    """Whether an open archive's arrays are compressed (np.savez_compressed's) rather than stored
    (np.savez's): a file written back keeps its reader's choice of size against speed (deflating
    a take's float32 positions saves a fifth of its size for 14 times the time to write it)."""
    return any(member.compress_type != zipfile.ZIP_STORED for member in data.zip.infolist())


def npz_array(path: Path, data, key: str) -> np.ndarray:
    """data[key] of plain numbers or strings; a truncated or corrupt member, or an object array,
    is a MotionFileError, not a zlib traceback or a pickle."""
    try:
        return data[key]
    except ValueError as e:
        if "allow_pickle" in str(e):
            raise MotionFileError(path, f"array {key!r} holds Python objects (a pickle), not numbers") from None
        raise MotionFileError(path, f"cannot read array {key!r} ({one_line(e)})") from None
    except Exception as e:
        raise MotionFileError(path, f"cannot read array {key!r} ({one_line(e)})") from None


def npz_object(path: Path, key: str, encoding: str = "ASCII"):
    """The array stored under `key`, read without running code: plain arrays as np.load gives
    them, object arrays (a pickle inside the member) through the restricted unpickler, which
    builds only containers, strings, numbers and numpy arrays. A pickle that imports anything
    else is a MotionFileError naming the import; nothing of it has run."""
    path = Path(path)
    with load_npz(path) as data:
        if key not in data.files:
            raise MotionFileError(path, f"no {key!r} array")
        try:
            return data[key]
        except ValueError as e:
            if "allow_pickle" not in str(e):
                raise MotionFileError(path, f"cannot read array {key!r} ({one_line(e)})") from None
        except Exception as e:
            raise MotionFileError(path, f"cannot read array {key!r} ({one_line(e)})") from None
    try:  # an object array: the member is an .npy header followed by a pickle
        with open_regular(path) as raw, zipfile.ZipFile(raw) as z, z.open(f"{key}.npy") as f:
            version = np.lib.format.read_magic(f)
            read_header = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
            if version not in read_header:
                raise MotionFileError(path, f"array {key!r}: .npy version {version} holds objects; not read")
            shape, _, _ = read_header[version](f)
            obj = load_arrays(f, encoding=encoding)
    except MotionFileError:
        raise
    except RefusedPickle as e:
        raise MotionFileError(
            path,
            f"array {key!r} is a pickle that imports {quoted(str(e), 80)} (not an array): refused, nothing was run",
        ) from None
    except Exception as e:
        raise MotionFileError(path, f"cannot read array {key!r} ({one_line(e)})") from None
    if not isinstance(obj, np.ndarray) or obj.shape != shape:
        raise MotionFileError(path, f"array {key!r}: the pickle does not hold a {shape} array")
    return obj


def one_line(e: BaseException, limit: int = 160) -> str:
    """An exception as "Type: message" on one short line. The message of a library's exception
    can quote the file (a member name, a header): non-printable characters come escaped and it
    is cut at `limit` characters."""
    text = printable(e, limit)
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def listed_keys(files: list[str], most: int = 8) -> str:
    """An archive's member names for a message: quoted (they are the file's text), at most `most`."""
    shown_keys = ", ".join(quoted(k, 30) for k in sorted(files)[:most])
    return (shown_keys + (f" and {len(files) - most} more" if len(files) > most else "")) or "none"
