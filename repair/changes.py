"""What the repair changed, face by face, for pictures: each face of the input and of the
repaired mesh gets a label saying whether it was kept, re-cut, thickened, added or dropped.

The labels are read from the geometry of the two meshes (exact face identity, then the
distance of each face's centroid to the other mesh's surface), so they hold for every
repair path without the stages keeping per-face records:

* an output face on exactly the same three points as an input face is *kept*;
* one whose centroid lies on the input surface (within ``0.05 * epsilon``) is *re-cut*
  (a piece of an input face where parts were united or an arrangement cut it);
* one about ``epsilon / 2`` away from the input surface (0.3 to 0.7 epsilon: sheets and
  wires are thickened by epsilon, centred on themselves) is *thickened*; when the repair
  closed no holes (``lids=False``, from its report), every new face up to 0.7 epsilon
  away is (the slabs' rims come closer than epsilon / 2);
* any other new face is *added* (lids over small holes, patches where rounding mended);
  when nothing was thickened (``thickened=False``) no face is called thickened.

An input face whose centroid is not on the output surface is *thickened* when it lies
about ``epsilon / 2`` inside the output (the middle of a slab), else *dropped* (an internal
face or part, a flap beside a hole).

Units are mm; vertices float64 (n, 3), faces int64 (m, 3). Pure: arrays in, arrays out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from repair.provenance import same_faces

__all__ = ["LABELS", "FaceChanges", "face_changes"]

KEPT, RECUT, THICKENED, ADDED, DROPPED = range(5)

#: Label number -> name, in the order of the numbers.
LABELS = ("kept", "re-cut", "thickened", "added", "dropped")

ON_SURFACE = 0.05   # x epsilon: a centroid this close to the other surface is on it
SLAB = (0.3, 0.7)   # x epsilon: the distance of a thickened face from its sheet or wire


@dataclass(frozen=True)
class FaceChanges:
    """``input``: a label (``LABELS`` index, uint8) per input face; ``output``: one per
    repaired face; ``counts``: faces per label name, for each side."""

    input: np.ndarray
    output: np.ndarray

    def counts(self) -> dict[str, dict[str, int]]:
        def tally(labels: np.ndarray) -> dict[str, int]:
            n = np.bincount(labels, minlength=len(LABELS))
            return {name: int(n[i]) for i, name in enumerate(LABELS) if n[i]}
        return {"input": tally(self.input), "output": tally(self.output)}


def _distances(points: np.ndarray, v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Distance of each point to the surface ``(v, f)`` (infinite when it has no faces)."""
    if len(points) == 0:
        return np.zeros(0)
    if len(f) == 0:
        return np.full(len(points), np.inf)
    import igl

    sq, _, _ = igl.point_mesh_squared_distance(
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(v, dtype=np.float64),
        np.ascontiguousarray(f, dtype=np.int64),
    )
    return np.sqrt(np.maximum(np.asarray(sq, dtype=np.float64), 0.0))


def face_changes(
    v_in: np.ndarray,
    f_in: np.ndarray,
    v_out: np.ndarray,
    f_out: np.ndarray,
    epsilon: float,
    *,
    thickened: bool = True,
    lids: bool = True,
) -> FaceChanges:
    """Label every face of the input ``(v_in, f_in)`` and of its repair ``(v_out, f_out)``;
    ``epsilon`` (mm) is the thickness the repair gave sheets and wires; ``thickened`` and
    ``lids``: whether its report says it thickened sheets or wires, and closed holes."""
    v_in = np.asarray(v_in, dtype=np.float64).reshape(-1, 3)
    f_in = np.asarray(f_in, dtype=np.int64).reshape(-1, 3)
    v_out = np.asarray(v_out, dtype=np.float64).reshape(-1, 3)
    f_out = np.asarray(f_out, dtype=np.int64).reshape(-1, 3)
    # STL coordinates are float32: compare the input on the values the repair started from
    v_in32 = v_in.astype(np.float32).astype(np.float64)
    on, slab_hi = ON_SURFACE * epsilon, SLAB[1] * epsilon
    slab_lo = SLAB[0] * epsilon if lids else on
    if not thickened:
        slab_lo = slab_hi = -1.0

    match = same_faces(v_in32, f_in, v_out, f_out)
    out = np.full(len(f_out), ADDED, dtype=np.uint8)
    out[match >= 0] = KEPT
    new = np.flatnonzero(match < 0)
    d_out = _distances(v_out[f_out[new]].mean(axis=1), v_in32, f_in)
    out[new[d_out <= on]] = RECUT
    out[new[(d_out > on) & (d_out >= slab_lo) & (d_out <= slab_hi)]] = THICKENED

    inp = np.full(len(f_in), DROPPED, dtype=np.uint8)
    inp[match[match >= 0]] = KEPT
    gone = np.flatnonzero(inp != KEPT)
    d_in = _distances(v_in32[f_in[gone]].mean(axis=1), v_out, f_out)
    inp[gone[d_in <= on]] = RECUT
    if thickened:
        inp[gone[(d_in >= SLAB[0] * epsilon) & (d_in <= slab_hi)]] = THICKENED
    return FaceChanges(inp, out)
