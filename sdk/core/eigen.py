"""The top eigenvector of a small symmetric matrix, for numba kernels (cyclic Jacobi rotations; no LAPACK, so the
kernels that use it compile quickly): the least-squares rotation of the ICP (Horn's 4 × 4 matrix) and the
dominant direction of a 3 × 3 scatter (the mirror plane of the frame priors).

Convention: ``A`` [n, n] float64 symmetric; the result is a unit vector whose sign is arbitrary (callers fix it).
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["top_eigenvector", "top_eigenvector_into"]


@njit(cache=True)
def top_eigenvector(A):
    """Unit eigenvector [n] of the largest eigenvalue of the symmetric ``A`` [n, n]."""
    n = A.shape[0]
    W, V = A.copy(), np.empty((n, n))
    return V[:, top_eigenvector_into(W, V)].copy()


@njit(cache=True)
def top_eigenvector_into(A, V) -> int:
    """The index b of the largest eigenvalue of the symmetric ``A`` [n, n], with ``V`` [n, n] (any values on entry)
    set to its eigenvectors: the unit vector is ``V[:, b]``. ``A`` is overwritten (diagonalised). No allocation:
    for kernels that solve many small matrices in a loop."""
    n = A.shape[0]
    for p in range(n):
        for q in range(n):
            V[p, q] = 1.0 if p == q else 0.0
    for _ in range(30):
        off, diag = 0.0, 0.0
        for p in range(n):
            diag += A[p, p] * A[p, p]
            for q in range(p + 1, n):
                off += A[p, q] * A[p, q]
        if off <= 1e-30 * diag or off == 0.0:                                   # diagonal to double precision
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                if A[p, q] == 0.0:
                    continue
                theta = (A[q, q] - A[p, p]) / (2.0 * A[p, q])
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):                                              # A ← Jᵀ A J
                    akp, akq = A[k, p], A[k, q]
                    A[k, p], A[k, q] = c * akp - s * akq, s * akp + c * akq
                for k in range(n):
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k], A[q, k] = c * apk - s * aqk, s * apk + c * aqk
                for k in range(n):                                              # V ← V J
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p], V[k, q] = c * vkp - s * vkq, s * vkp + c * vkq
    best = 0
    for i in range(1, n):
        if A[i, i] > A[best, best]:
            best = i
    return best
