"""One BLAS thread for the small matrix work inside the loop (refits, re-clusterings).

``threadpoolctl.threadpool_limits`` finds the loaded BLAS libraries again on every call: it
walks every shared library of the process (Drake, OpenCV, numba's LLVM, ...) and asks each
for its thread pools, some milliseconds per call in a simulation, paid at every refit. A
``ThreadpoolController`` does that walk once; its ``limit`` then only sets and restores the
thread counts. The controller is built at the first call, when the loop is running and every
BLAS it uses (numpy's, scipy's) is loaded; a BLAS loaded later is not limited (none is: the
libraries that ship one are imported before a loop starts).
"""

from __future__ import annotations

from threadpoolctl import ThreadpoolController

_controller: ThreadpoolController | None = None


def one_blas_thread():
    """Context manager: the BLAS libraries run on one thread inside it (restored after)."""
    global _controller
    if _controller is None:
        _controller = ThreadpoolController()
    return _controller.limit(limits=1, user_api="blas")
