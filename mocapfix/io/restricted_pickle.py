"""Reading the pickles that public motion formats contain, without running code from the file.

A pickle is a program: its GLOBAL opcodes import any callable and its REDUCE opcodes call it, so
`np.load(..., allow_pickle=True)` on a shared file can run `os.system`. Yet public formats store
object arrays: VideoPose3D's data_3d_h36m.npz pickles a {subject: {action: array}} dict, some
AMASS releases pickle the gender string, and SMPL-family model files are pickled dicts of arrays.
These hold only containers, strings, numbers and numpy arrays (and a scipy sparse J_regressor),
so an unpickler that can import nothing but numpy's array and dtype reconstructors (and the
sparse matrix classes, built without calling their constructors) reads every real file and
refuses anything else with the name of what the file tried to import. The same idea as
torch.load(weights_only=True).
"""

from __future__ import annotations

import copyreg
import io
import pickle

# (module, name) -> what find_class returns. numpy 2 renamed numpy.core to numpy._core; files
# written by either name both appear in the wild (and Python 2's pickles of the SMPL models).
_NUMPY = {
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"),
    ("numpy._core.multiarray", "scalar"),
    ("numpy.core.numeric", "_frombuffer"),
    ("numpy._core.numeric", "_frombuffer"),
}
# Sparse matrices pickle as copyreg._reconstructor(cls, object, None) plus a __dict__ of arrays:
# the instance is made with object.__new__ and its fields set, no scipy code runs.
_SPARSE = {
    (module, name)
    for name in ("csc_matrix", "csr_matrix", "coo_matrix")
    for module in ("scipy.sparse", f"scipy.sparse.{name[:3]}", f"scipy.sparse._{name[:3]}")
}


class RefusedPickle(pickle.UnpicklingError):
    """The pickle imports something other than arrays: the file is refused, nothing was run."""


def _safe_reconstructor(cls, base, state):
    """copyreg._reconstructor for the sparse classes only (a class reaches here only through
    find_class, but the check keeps that true if find_class grows)."""
    where = (getattr(cls, "__module__", ""), getattr(cls, "__name__", ""))
    if base is not object or state is not None or where not in _SPARSE:
        raise RefusedPickle(f"copyreg._reconstructor of {'.'.join(where)}")
    return copyreg._reconstructor(cls, base, state)


# Python 2's module names, as protocols 0-2 write them (pickle maps them in its own find_class).
_PY2_MODULES = {"copy_reg": "copyreg", "__builtin__": "builtins"}


class _ArraysOnly(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        module = _PY2_MODULES.get(module, module)
        if (module, name) in _NUMPY:
            return super().find_class(module, name)
        if (module, name) == ("_codecs", "encode"):  # bytes in protocol-2 pickles (Python 2 files)
            return super().find_class(module, name)
        if (module, name) == ("copyreg", "_reconstructor"):
            return _safe_reconstructor
        if (module, name) in _SPARSE:
            return super().find_class(module, name)  # imports scipy.sparse: a library, not the file's code
        if (module, name) == ("builtins", "object"):
            return object
        raise RefusedPickle(f"{module}.{name}")


def load_arrays(data: bytes | io.BufferedIOBase, encoding: str = "ASCII"):
    """Unpickle `data` (bytes or a binary file) allowing only containers, strings, numbers and
    numpy arrays (and scipy sparse matrices). RefusedPickle names the first other import; the
    callable is never looked up, let alone called. encoding: "latin1" for Python 2 pickles."""
    f = io.BytesIO(data) if isinstance(data, (bytes, bytearray)) else data
    return _ArraysOnly(f, encoding=encoding).load()
