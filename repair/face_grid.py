"""A uniform grid over the faces of a mesh, to find the faces near a few others without
testing all of them: what the exact intersection tests of a changed region need.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3). Vectorised numpy.
"""

from __future__ import annotations

import numpy as np

from repair.rows import ranges, sort_with_positions

__all__ = ["FaceGrid"]


class FaceGrid:
    """Finds the faces near a few others: those whose bounding box meets the (slightly
    grown) box of one of them, and perhaps a few more -- a superset, which is all an
    exact test of the region needs.

    Built once per mesh: grid cells as large as 99 % of the faces' boxes, and each face
    that fits in a cell listed under the cell of its low corner, sorted by cell. A face
    that fits and meets a box has its low corner between the box's low corner less one
    cell and its high corner, so a query gathers the faces listed under those cells for
    each asked face. Larger faces are listed under every cell their box covers (which a
    box they meet covers too), or, beyond 64 cells, tested box against box. Where cells
    are coarse for the asked faces (a CAD mesh mixes sizes), the gathered faces are
    tested box against box too, while that is cheap (gathered x asked <= 1M). Boxes are
    grown by ``1e-6`` of the largest coordinate, so the grid stays valid while vertices
    move by less than that (float32 rounding choices move them by one float32 ulp, ~6e-8
    of it).
    """

    def __init__(self, v: np.ndarray, f: np.ndarray) -> None:
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        pad = 1e-6 * (float(np.abs(v).max()) if len(v) else 1.0) or 1e-6
        self.lo = np.minimum(np.minimum(a, b), c) - pad
        self.hi = np.maximum(np.maximum(a, b), c) + pad
        self.lo_t, self.hi_t = np.ascontiguousarray(self.lo.T), np.ascontiguousarray(self.hi.T)
        self.m = len(f)
        if self.m == 0:
            return
        self.origin = self.lo.min(axis=0)
        span = float((self.hi.max(axis=0) - self.origin).max())
        ext = (self.hi - self.lo).max(axis=1)
        self.h = self._cell_size(ext, span)
        self.n = int(span / self.h) + 3
        self.fits = ext <= self.h
        listed = np.flatnonzero(self.fits)
        k = self._key(self._cell(self.lo[listed]))
        # Larger faces are listed under every cell their box covers, up to 64 of them.
        big = np.flatnonzero(~self.fits)
        lo_c, hi_c = self._cell(self.lo[big]), self._cell(self.hi[big])
        few = (hi_c - lo_c + 1).prod(axis=1) <= 64
        self.big = big[~few]  # the rest: tested box against box
        if np.any(few):
            bk, rows = self._cells_in(lo_c[few], hi_c[few])
            k = np.r_[k, bk]
            listed = np.r_[listed, big[few][rows]]
        order, self.sorted_keys = sort_with_positions(k)
        self.sorted_faces = listed[order]

    def _cell_size(self, ext: np.ndarray, span: float) -> float:
        """The edge of a cell (mm): the smallest of a few quantiles of the faces' box
        sizes (``ext``) at which listing each face under every cell its box covers takes
        at most ``4 m`` listings -- fine cells where most faces are small, so a query
        gathers few faces beyond those it asks for even where a few faces are long (a
        gear's flanks) -- and never below ``span / 1024`` (keys stay small)."""
        floor = max(span / 1024.0, 1e-300)
        sizes = np.maximum(np.quantile(ext, [0.5, 0.75, 0.9, 0.99]), floor)
        for h in sizes[:-1]:
            lo = np.floor((self.lo - self.origin) / h)
            cover = (np.floor((self.hi - self.origin) / h) - lo + 1).prod(axis=1)
            if float(cover.sum()) <= 4.0 * self.m:
                return float(h)
        return float(sizes[-1])

    def _cells_in(self, lo_c: np.ndarray, hi_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Keys of all cells in each box of cells ``lo_c..hi_c`` (k, 3), and for each key
        the row it came from."""
        dims = hi_c - lo_c + 1
        cover = dims.prod(axis=1)
        local = np.arange(int(cover.sum())) - np.repeat(np.cumsum(cover) - cover, cover)
        d = np.repeat(dims, cover, axis=0)
        ijk = np.stack([local // (d[:, 1] * d[:, 2]), (local // d[:, 2]) % d[:, 1],
                        local % d[:, 2]], axis=1)  # fmt: skip
        rows = np.repeat(np.arange(len(lo_c)), cover)
        return self._key(lo_c[rows] + ijk), rows

    def _cell(self, x: np.ndarray) -> np.ndarray:
        return np.clip(np.floor((x - self.origin) / self.h), 0, self.n - 1).astype(np.int64)

    def _key(self, c: np.ndarray) -> np.ndarray:
        return (c[..., 0] * self.n + c[..., 1]) * self.n + c[..., 2]

    def _meet(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Mask over ``a``: faces whose box meets the box of a face of ``b``, box against
        box in chunks of 64 of the shorter list."""
        lo, hi = self.lo, self.hi
        out = np.zeros(len(a), dtype=bool)
        for s in range(0, min(len(a), len(b)), 64):
            if len(a) <= len(b):
                g = a[s : s + 64]
                hit = (lo[g, None] <= hi[None, b]) & (hi[g, None] >= lo[None, b])
                out[s : s + 64] = hit.all(axis=2).any(axis=1)
            else:
                g = b[s : s + 64]
                hit = (lo[None, a] <= hi[g, None]) & (hi[None, a] >= lo[g, None])
                out |= hit.all(axis=2).any(axis=0)
        return out

    def _meeting(
        self, first: np.ndarray, count: np.ndarray, asked: np.ndarray, chunk: int
    ) -> list[np.ndarray]:
        """The faces listed under cells ``first[i] .. first[i] + count[i]`` (positions in
        the sorted listing) whose box meets that of face ``asked[i]`` -- cells can be
        coarse -- box-tested ``chunk`` listings at a time (memory); with repeats."""
        out = []
        ends = np.cumsum(count)
        steps = np.arange(1, 1 + int(ends[-1]) // chunk) * chunk
        cuts = np.unique(np.r_[0, np.searchsorted(ends, steps), len(count)])
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            c = count[a:b]
            cand = self.sorted_faces[ranges(first[a:b], c)]
            by = np.repeat(asked[a:b], c)
            for k in range(3):  # axis by axis, on ever fewer pairs
                lo, hi = self.lo_t[k], self.hi_t[k]
                hit = (lo[cand] <= hi[by]) & (hi[cand] >= lo[by])
                cand, by = cand[hit], by[hit]
            out.append(cand)
        return out

    def near(self, which: np.ndarray, chunk: int = 2**20) -> np.ndarray:
        """Sorted indices of the faces near ``which`` (``which`` included); cell listings
        are box-tested ``chunk`` at a time."""
        which = np.asarray(which, dtype=np.int64)
        if len(which) == 0 or self.m == 0:
            return which
        if len(which) > self.m // 5:
            return np.arange(self.m)  # most of the mesh: one global test is cheaper
        found = [which]
        # Cells from (low corner - one cell) to the high corner of each asked face.
        lo_c, hi_c = self._cell(self.lo[which] - self.h), self._cell(self.hi[which])
        few = (hi_c - lo_c + 1).prod(axis=1) <= 4096
        if np.any(few):
            keys, rows = self._cells_in(lo_c[few], hi_c[few])
            first = np.searchsorted(self.sorted_keys, keys, side="left")
            count = np.searchsorted(self.sorted_keys, keys, side="right") - first
            if int(count.sum()) <= 8 * self.m + chunk:
                found.extend(self._meeting(first, count, which[few][rows], chunk))
            else:
                # Coarse cells and many asked faces: every face listed in their cells (a
                # superset; box-testing each listing would cost more than it saves).
                keys = np.unique(keys)
                first = np.searchsorted(self.sorted_keys, keys, side="left")
                count = np.searchsorted(self.sorted_keys, keys, side="right") - first
                found.append(self.sorted_faces[ranges(first, count)])
        if len(self.big):
            found.append(self.big[self._meet(self.big, which)])
        huge = which[~few]
        if len(huge):
            found.append(np.flatnonzero(self._meet(np.arange(self.m), huge)))
        # A mark per face, not a sort: the listings repeat faces many times over.
        near = np.zeros(self.m, dtype=bool)
        for idx in found:
            near[idx] = True
        return np.flatnonzero(near)
