"""The exact self-intersection test started in the background: slabs in forked
children, so the caller's process is free for other work until it asks for the result.

:func:`repair.intersections.intersecting_face_pairs` tests slab 0 in the calling process
and the others in forked children; :func:`start_face_pairs` forks those children at
once (the same slabs, the same libigl test, so the same pairs) and returns: slab 0 is
tested when the result is asked, or, on a large mesh, in a child of its own too. A check
then computes its edge census -- and a caller its speculative next stage -- while CGAL
runs on the other CPU(s). Units mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

import numpy as np

from repair.forked import Forked
from repair.intersections import (
    PARALLEL_MIN_FACES,
    _pairs,
    check_box_pair_budget,
    face_slabs,
    intersecting_face_pairs,
)
from repair.rows import unique_rows
from repair.workers import cpu_workers

__all__ = ["BACKGROUND_MIN_FACES", "PendingPairs", "start_face_pairs"]

#: Meshes with at least this many faces are tested in the background (one more fork than
#: :func:`intersecting_face_pairs` makes; on a smaller mesh the work it frees the caller
#: for is small too, and the fork's CPU time is not).
BACKGROUND_MIN_FACES = max(PARALLEL_MIN_FACES, 50_000)


class PendingPairs:
    """:func:`intersecting_face_pairs` of a mesh, being computed; :meth:`result` waits for
    it. A child that fails (a native crash included) has its slab tested again here."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self._v, self._f = vertices, faces
        self._children: list[Forked] = []
        self._here: np.ndarray | None = None  # the slab tested here when asked
        self._pairs: np.ndarray | None = None

    @property
    def running(self) -> bool:
        """True while forked children test the pairs (the caller is free meanwhile)."""
        return bool(self._children)

    def result(self) -> np.ndarray:
        """Unordered pairs (k, 2) of intersecting faces: sorted (i < j), unique."""
        if self._pairs is None:
            self._pairs = self._collect() if self._children else intersecting_face_pairs(
                self._v, self._f
            )
        return self._pairs

    def cancel(self) -> None:
        """Stop the children (their result is not wanted): killed and reaped."""
        for child in self._children:
            child.cancel()
        self._children = []
        self._here = None

    def _start(self, slabs: list[np.ndarray], here: np.ndarray | None = None) -> None:
        v, f = self._v, self._f
        self._children = [Forked(lambda idx=idx: _slab_pairs(v, f, idx)) for idx in slabs]
        self._here = here

    def _collect(self) -> np.ndarray:
        found = []
        if self._here is not None:
            found.append(_slab_pairs(self._v, self._f, self._here))
            self._here = None
        found += [np.asarray(c.result(), dtype=np.int64).reshape(-1, 2) for c in self._children]
        self._children = []
        pairs = np.vstack(found)
        if len(pairs) == 0:
            return np.zeros((0, 2), dtype=np.int64)
        return unique_rows(np.sort(pairs, axis=1))


def _slab_pairs(v: np.ndarray, f: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The crossing pairs among the faces ``idx`` (indices into ``f``), unsorted."""
    check_box_pair_budget(v, f[idx])  # raised again where a child failed
    return idx[_pairs(v, f[idx])]


def start_face_pairs(vertices: np.ndarray, faces: np.ndarray) -> PendingPairs:
    """Start :func:`repair.intersections.intersecting_face_pairs` on ``(vertices, faces)``:
    on a mesh of :data:`BACKGROUND_MIN_FACES` or more, each slab in its own forked child,
    started now; on one of :data:`~repair.intersections.PARALLEL_MIN_FACES` or more, the
    children of slabs 1.. started now and slab 0 tested when :meth:`PendingPairs.result`
    is asked (the caller's work in between runs beside them: mikedh_box's check, 9k
    faces, its edge census); otherwise the test runs when the result is asked."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    pending = PendingPairs(v, f)
    workers = cpu_workers()
    if len(f) < PARALLEL_MIN_FACES or workers < 2:
        return pending
    import igl.copyleft.cgal  # noqa: F401 -- imported once here, not once per child

    slabs = face_slabs(v, f, workers)
    if len(f) < BACKGROUND_MIN_FACES:
        pending._start(slabs[1:], here=slabs[0])
    else:
        pending._start(slabs)
    return pending
