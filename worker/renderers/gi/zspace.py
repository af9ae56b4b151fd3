"""Index of the symmetric terms of the tensor (polynomial-gi §4, eq. 25): the diffuse bounces
beyond the first (or second) vertex from the eye multiply the product of the diffuse
equivalents d̄_z of the units they hit, a monomial that only depends on the *multiset* z of
units, so all orderings of a path's units share one tensor entry ("symmetric terms merged").

Multisets of size s over U units are ranked by the combinatorial number system: sorted
a_1 ≤ … ≤ a_s map to the strictly increasing b_i = a_i + (i − 1), ranked Σ C(b_i, i); sizes are
laid out one after the other, so ``index`` does not depend on the largest size in use.
"""
from __future__ import annotations

from itertools import combinations_with_replacement
from math import comb

import numpy as np

MAX_Z = 3           # at most N − 1 = 3 diffuse-equivalent vertices (4 bounces)
EMPTY = 32767       # padding of unused multiset slots (sorts last)


def size(U: int, S: int) -> int:
    """Number of multisets of size ≤ S over U units."""
    return sum(comb(U + s - 1, s) for s in range(S + 1)) if U > 0 else 1


def offsets(U: int) -> np.ndarray:
    """(MAX_Z + 2,) int64: start index of each multiset size."""
    return np.array([size(U, s - 1) if s > 0 else 0 for s in range(MAX_Z + 2)], np.int64)


def binom_table(U: int) -> np.ndarray:
    """(U + MAX_Z + 1, MAX_Z + 1) int64 C(n, k)."""
    n = U + MAX_Z + 1
    return np.array([[comb(a, b) for b in range(MAX_Z + 1)] for a in range(n)], np.int64)


def index(z: np.ndarray, zc: np.ndarray, U: int) -> np.ndarray:
    """Ranks (R,) int64 of sorted multisets z (R, MAX_Z) (padding EMPTY) of sizes zc (R,)."""
    C = binom_table(U)
    off = offsets(U)
    r = off[zc].copy()
    for i in range(MAX_Z):
        use = zc > i
        b = np.where(use, z[:, i].astype(np.int64) + i, 0)
        r += np.where(use, C[np.minimum(b, len(C) - 1), i + 1], 0)
    return r


def insert(z: np.ndarray, zc: np.ndarray, unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Add unit (R,) (≥ 0) to the sorted multisets z (R, MAX_Z); returns new (z, zc)."""
    z = z.copy()
    z[np.arange(len(z)), np.minimum(zc, MAX_Z - 1)] = unit
    z.sort(axis=1)
    return z, zc + 1


def enumerate_all(U: int, S: int) -> list[tuple[int, ...]]:
    """All multisets of size ≤ S, in index order."""
    out = []
    for s in range(S + 1):
        combos = list(combinations_with_replacement(range(U), s))
        # order by rank: colex of b_i = a_i + i
        combos.sort(key=lambda a: sum(comb(x + i, i + 1) for i, x in enumerate(a)))
        out += combos
    return out
