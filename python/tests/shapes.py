"""Closed meshes made with numpy for the tests: an icosphere and a torus."""

from __future__ import annotations

import numpy as np


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed unit icosphere: (vertices float32, faces int64), outward winding."""
    p = (1 + 5**0.5) / 2
    v = [
        (-1, p, 0), (1, p, 0), (-1, -p, 0), (1, -p, 0),
        (0, -1, p), (0, 1, p), (0, -1, -p), (0, 1, -p),
        (p, 0, -1), (p, 0, 1), (-p, 0, -1), (-p, 0, 1),
    ]  # fmt: skip
    f = [
        (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11),
        (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8),
        (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
        (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1),
    ]  # fmt: skip
    verts = [np.array(x, np.float64) / np.linalg.norm(x) for x in v]
    faces = list(f)
    mid: dict[tuple[int, int], int] = {}  # edge -> its midpoint vertex

    def middle(a: int, b: int) -> int:
        key = (min(a, b), max(a, b))
        if key not in mid:
            m = verts[a] + verts[b]
            verts.append(m / np.linalg.norm(m))
            mid[key] = len(verts) - 1
        return mid[key]

    for _ in range(subdivisions):
        new = []
        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return np.array(verts, np.float32), np.array(faces, np.int64)


def torus(major: float, minor: float, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed torus around the z axis: `n` sections around it, `m` around the tube;
    (vertices float32, faces int64), outward winding."""
    a = 2 * np.pi * np.arange(n) / n
    b = 2 * np.pi * np.arange(m) / m
    aa, bb = np.meshgrid(a, b, indexing="ij")
    r = major + minor * np.cos(bb)
    v = np.stack([r * np.cos(aa), r * np.sin(aa), minor * np.sin(bb)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    p00 = i * m + j
    p10 = ((i + 1) % n) * m + j
    p01 = i * m + (j + 1) % m
    p11 = ((i + 1) % n) * m + (j + 1) % m
    f = np.concatenate(
        [np.stack([p00, p10, p11], -1).reshape(-1, 3), np.stack([p00, p11, p01], -1).reshape(-1, 3)]
    )
    return v.astype(np.float32), f.astype(np.int64)
