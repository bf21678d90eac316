"""Independent parts of one job run side by side on a small shared pool of threads.

For work that leaves Python's GIL while it runs: compiled kernels declared ``nogil`` (the batched ICP) and
onnxruntime sessions. The number of parts a caller may use is scoped with ``kernel_workers(n)``, a context variable
(each thread and task sees its own; 1 outside any scope and inside the pool's own threads, so parts never nest).
Idle pool threads block instead of spinning: a waiting pool takes no time from onnxruntime or Python.

Convention: ``run_parts`` keeps the order of its parts; the first part runs in the calling thread.

``single_thread_blas()`` scopes numpy's BLAS (OpenBLAS) to one thread: its own worker threads spin for a while after
each threaded product and took the cores from the next frame's side-by-side onnxruntime runs (sofa-partial: 8-copy
inference 27 → 40 ms after the turn classifier's products); the pipeline's products are too small to gain from them.
"""
from __future__ import annotations

import contextlib
import contextvars
import os
import threading
from concurrent.futures import ThreadPoolExecutor

__all__ = ["MAX_WORKERS", "kernel_workers", "workers", "split_ranges", "run_parts", "single_thread_blas"]

MAX_WORKERS = 8                 # parts side by side, at most (the pool's size + the calling thread)

_WORKERS: contextvars.ContextVar = contextvars.ContextVar("equipose_kernel_workers", default=1)
_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()
_BLAS = None                    # threadpoolctl's controller of the loaded BLAS libraries, found once


@contextlib.contextmanager
def kernel_workers(n: int):
    """Within this block, ``workers()`` is ``n`` (clipped to 1 … ``MAX_WORKERS``)."""
    token = _WORKERS.set(max(1, min(int(n), MAX_WORKERS)))
    try:
        yield
    finally:
        _WORKERS.reset(token)


def workers() -> int:
    """Parts the current scope may run side by side (``kernel_workers``; 1 by default)."""
    return _WORKERS.get()


def split_ranges(count: int, parts: int) -> list:
    """``count`` items as at most ``parts`` contiguous (start, stop) ranges of near-equal size, in order."""
    parts = max(1, min(int(parts), int(count)))
    base, extra = divmod(int(count), parts)
    out, start = [], 0
    for p in range(parts):
        stop = start + base + (p < extra)
        out.append((start, stop))
        start = stop
    return out


def _pool() -> ThreadPoolExecutor:
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(MAX_WORKERS - 1, thread_name_prefix="equipose-part")
        return _POOL


def _forget_pool_in_child() -> None:
    """A forked child has none of its parent's threads (its copy of the pool would queue parts that never run): it
    starts its own pool when it first needs one."""
    global _POOL, _POOL_LOCK
    _POOL, _POOL_LOCK = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_pool_in_child)


def run_parts(fn, arg_lists: list) -> list:
    """[fn(*args) for args in ``arg_lists``], the parts side by side (the first in this thread); an exception of any
    part is raised here after every part has finished."""
    if len(arg_lists) <= 1:
        return [fn(*args) for args in arg_lists]
    futures = [_pool().submit(fn, *args) for args in arg_lists[1:]]
    try:
        first = fn(*arg_lists[0])
    finally:
        rest = [f.exception() for f in futures]                               # wait for all before raising
    for err in rest:
        if err is not None:
            raise err
    return [first] + [f.result() for f in futures]


def single_thread_blas():
    """A context in which numpy's BLAS runs on one thread (``threadpoolctl``; the libraries are looked up once)."""
    global _BLAS
    if _BLAS is None:
        from threadpoolctl import ThreadpoolController
        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")
