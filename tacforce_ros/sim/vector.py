"""Small 3-vector helpers for the step path: batched (numpy's general cross costs ~20 us a
call), and single vectors as tuples of floats (a numpy call on 3 elements costs ~0.3-0.9 us,
the same arithmetic on floats a tenth of that)."""
from __future__ import annotations

import numpy as np

Vec3 = tuple[float, float, float]

# Component j of a x b is a[j+1] b[j+2] - a[j+2] b[j+1] (indices mod 3).
_NEXT = np.array([1, 2, 0])
_AFTER_NEXT = np.array([2, 0, 1])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b for (..., 3) arrays, broadcasting: the textbook products and differences, with
    the components gathered by take (a third of the calls of a per-component stack)."""
    return (a.take(_NEXT, -1) * b.take(_AFTER_NEXT, -1)
            - a.take(_AFTER_NEXT, -1) * b.take(_NEXT, -1))


def dot3(a: Vec3, b: Vec3) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def add3(a: Vec3, b: Vec3, scale: float = 1.0) -> Vec3:
    """a + scale b."""
    return (a[0] + scale * b[0], a[1] + scale * b[1], a[2] + scale * b[2])


def sub3(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def scale3(scale: float, a: Vec3) -> Vec3:
    return (scale * a[0], scale * a[1], scale * a[2])


def cross3(a: Vec3, b: Vec3) -> Vec3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def matvec3(m, v: Vec3) -> Vec3:
    """M v, M given by its rows (3 x 3 nested lists or tuples)."""
    (a, b, c), (d, e, f), (g, h, i) = m
    return (a * v[0] + b * v[1] + c * v[2], d * v[0] + e * v[1] + f * v[2],
            g * v[0] + h * v[1] + i * v[2])


def matTvec3(m, v: Vec3) -> Vec3:
    """M^T v, M given by its rows (3 x 3 nested lists or tuples)."""
    (a, b, c), (d, e, f), (g, h, i) = m
    return (a * v[0] + d * v[1] + g * v[2], b * v[0] + e * v[1] + h * v[2],
            c * v[0] + f * v[1] + i * v[2])
