"""Byte-identical outputs: torch numerics whose result does not depend on the thread count.

torch's CPU kernels split work between intra-op threads, and some splits change the order of
floating-point additions: reductions with few outputs (``x.sum()``, a per-leaf sum over many
pixels) accumulate one partial sum per thread, and the BLAS behind ``matmul`` / ``bmm`` /
``einsum`` may split the inner (reduced) dimension between threads. The result then differs in
the last bits with the number of threads, and 200 Adam steps amplify that into fit errors that
differ in the third digit: the same capture converted by ``convert`` (all cores) and by
``batch`` (one thread per job) would give different stages.

The stages that compute with torch (the registration, the renderer behind the texture bake)
therefore run under :func:`deterministic_torch`: one intra-op thread for the block (the caller's
setting is restored after), so every reduction has one fixed order. The parallelism we give up
is small (the fit's per-step tensors are small; measured in ``benchmarks/batch.py``' notes) and
``leaffit-usd batch`` gets it back by converting several captures at once.
Randomness is seeded explicitly where it exists (``FitParams.seed``, ``SegmentParams.seed``).
The bytes are those of one machine and install: torch and OpenBLAS choose kernels by the CPU's
vector instructions, so another CPU (or other numpy / scipy releases) can differ in the last bits
(``benchmarks/machine.py`` records both with every benchmark result).

The same block also runs numpy's BLAS (OpenBLAS) on one thread (``threadpoolctl``). Not for the
bytes (OpenBLAS splits a product over its output, not over the summed dimension) but for time:
the registration's Gauss-Newton products are tall and thin ((16384, 96)^T (16384, 96)), and on a
busy machine (more runnable threads than cores) OpenBLAS' threads spin waiting for each other:
measured 10x slower than one thread on the 2-core benchmark machine under load (benchmarks/scale.py).
"""
from __future__ import annotations

import contextlib
import functools
import threading

_lock = threading.RLock()
_depth = 0          # blocks inside deterministic_torch now, over all threads
_saved = None       # (torch threads, threadpoolctl limits) from before the first of them


@contextlib.contextmanager
def deterministic_torch():
    """Run the block with one torch intra-op thread and one BLAS thread (both restored after;
    re-entrant, and thread-safe: the settings are process-wide, so they are restored when the
    last block still inside, in any thread, leaves, not when the first one to enter does)."""
    import torch
    from threadpoolctl import threadpool_limits

    global _depth, _saved
    with _lock:
        if _depth == 0:
            _saved = (torch.get_num_threads(), threadpool_limits(limits=1, user_api="blas"))
            if _saved[0] != 1:
                torch.set_num_threads(1)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                threads, blas = _saved
                _saved = None
                blas.restore_original_limits()
                if threads != 1:
                    torch.set_num_threads(threads)


def deterministic(fn):
    """Decorator: call ``fn`` under :func:`deterministic_torch`."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with deterministic_torch():
            return fn(*args, **kwargs)

    return wrapper


def one_blas_thread(fn):
    """Decorator: call ``fn`` with numpy's BLAS on one thread (threadpoolctl; restored after),
    for time, not bytes: on 2 cores OpenBLAS' second thread spins waiting for the first and takes
    the core another worker needs (the ``segment`` command: many small products, its kd-tree
    queries on both cores). No torch import."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper
