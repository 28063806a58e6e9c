"""numpy's BLAS on one thread while fix works.

fix's products (motion matching's search, the fill policy's measurement over cut holes) are many
small ones, for which BLAS's own thread per core costs more in waking and waiting than it
computes: `fix` on 16 copies of the CMU takes (47.5 min of motion, --jobs 1, 2 cores) took 135
CPU-seconds and 72 s with them, 63 and 45 on one (docs/performance.md, 3c); with workers each
one's BLAS threads fought the others'. The outputs are the same bytes. Spreading a run over cores
is --jobs' work. torch's threads are left as they are (the model's windows use them).
"""

from __future__ import annotations

from threadpoolctl import threadpool_limits


def one_blas_thread():
    """numpy's BLAS on one thread from now until the returned limiter's restore_original_limits()
    (or its `with` block's end)."""
    return threadpool_limits(limits=1, user_api="blas")


def on_one_blas_thread(function):
    """function with numpy's BLAS on one thread while it runs (the threads as they were after)."""
    return threadpool_limits.wrap(limits=1, user_api="blas")(function)
