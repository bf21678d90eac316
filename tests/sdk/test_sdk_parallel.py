"""Parts side by side (``equipose.core.parallel``): ranges cover the items in order, results keep their order,
the scope sets how many parts a caller may use, and a part's error reaches the caller."""
import threading

import pytest

from equipose.core.parallel import MAX_WORKERS, kernel_workers, run_parts, split_ranges, workers


@pytest.mark.parametrize("count, parts", [(1, 2), (5, 2), (6, 3), (7, 8), (16, 3)])
def test_split_ranges_cover_the_items_in_order(count, parts):
    ranges = split_ranges(count, parts)
    assert len(ranges) == min(count, parts)
    assert ranges[0][0] == 0 and ranges[-1][1] == count
    assert all(a[1] == b[0] for a, b in zip(ranges, ranges[1:]))                # contiguous
    sizes = [b - a for a, b in ranges]
    assert max(sizes) - min(sizes) <= 1 and min(sizes) >= 1


def test_run_parts_keeps_order_and_uses_other_threads():
    seen = {}

    def part(i):
        seen[i] = threading.get_ident()
        return i * i

    assert run_parts(part, [(i,) for i in range(5)]) == [0, 1, 4, 9, 16]
    assert seen[0] == threading.get_ident()                                     # the first part runs here
    assert all(seen[i] != threading.get_ident() for i in range(1, 5))          # the others on the pool
    assert run_parts(part, []) == [] and run_parts(part, [(3,)]) == [9]


def test_scope_sets_the_workers_and_parts_do_not_nest():
    assert workers() == 1
    with kernel_workers(3):
        assert workers() == 3
        inner = run_parts(lambda: workers(), [(), (), ()])
        assert inner[0] == 3 and inner[1:] == [1, 1]                            # pool threads: their own scope
        with kernel_workers(100):
            assert workers() == MAX_WORKERS
    assert workers() == 1


def test_a_part_s_error_reaches_the_caller():
    def part(i):
        if i == 2:
            raise ValueError("part 2 failed")
        return i

    with pytest.raises(ValueError, match="part 2"):
        run_parts(part, [(0,), (1,), (2,)])


def test_single_thread_blas_scopes_numpy_s_blas_to_one_thread():
    threadpoolctl = pytest.importorskip("threadpoolctl")
    from equipose.core.parallel import single_thread_blas

    def blas_threads():
        return [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]

    before = blas_threads()
    with single_thread_blas():
        assert blas_threads() and all(n == 1 for n in blas_threads())
    assert blas_threads() == before


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs os.fork")
def test_a_forked_child_runs_parts_on_its_own_pool():
    import os
    # the parent's pool with all its threads started: a child copying it would queue parts that never run
    assert run_parts(lambda i: i + 1, [(i,) for i in range(MAX_WORKERS)]) == list(range(1, MAX_WORKERS + 1))
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:                                                                # child: would hang on the parent's pool
        try:
            ok = run_parts(lambda i: i * 2, [(1,), (2,), (3,)]) == [2, 4, 6]
            os.write(w, b"1" if ok else b"0")
        finally:
            os._exit(0)
    os.close(w)
    import signal
    import time
    deadline = time.monotonic() + 30.0
    while os.waitpid(pid, os.WNOHANG) == (0, 0):                               # a hung child fails, not blocks
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            pytest.fail("the forked child hung on its parent's pool")
        time.sleep(0.05)
    assert os.read(r, 1) == b"1"
