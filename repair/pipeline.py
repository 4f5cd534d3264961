"""As-exact-as-possible repair (Attene 2018, Sec. 4): any triangle soup in, a printable
solid out, thickened only where it has to be.

Stages (each timed in the report; :func:`repair_mesh` reads as this list):

1. ``check_input`` round to float32, what a binary STL stores and what is written, and
   check exactly that (:func:`repair.rounding.round_input`);
2. ``clean``   weld exactly coincident vertices, move degenerate triangles to a list of
   segments (wires), keep one layer of equivalent triangles (:mod:`repair.clean`);
   ``scan_cleanup``: a scanned mesh (asked for, or one that looks like a scan) loses its
   spikes, specks, near-degenerate edges and ragged boundary faces (:mod:`repair.scan`);
   ``stitch``: join the boundaries of different patches that run within gamma = eps/4 of
   each other (Attene Sec. 5.2, :mod:`repair.stitch`), so a cracked surface closes;
   ``holes``: close the small holes of almost-closed shells with lids (:mod:`repair.holes`),
   so an open scan becomes a solid instead of a sheet; a closed body written twice (a copy
   within gamma, same faces) is kept once (:func:`repair.union.without_copies`);
3. ``union``   fast path: an input made only of closed, edge-manifold shells that overlap
   one another (a typical CAD export) is united by manifold3d's boolean union
   (:mod:`repair.union`), then finished as in 5;
4. ``hull_and_thicken`` otherwise: exact arrangement of the self-intersections (CGAL via
   libigl), the outer hull of its cells -- solid hull and zero-thickness sheets; internal
   faces and nested parts go -- and sheets become slabs of thickness eps, visible wires
   eps-prisms, united with the hull (:mod:`repair.hull_and_thicken`);
5. ``finish``  round to float32 avoiding crossings, verify with the exact check, mend
   where rounding broke anything (:mod:`repair.finish`); remove cavity shells thinner
   than a hair, which the winding number on both sides of their faces exposes
   (:mod:`repair.junk`), and fill slits and blades thinner than a hair
   (:mod:`repair.hairline`);
6. ``deviation`` Attene's deviation D (:mod:`repair.deviation`), and ``report``:
   manifold-connected parts, volume, what was done (:mod:`repair.report`).

``fallback`` (:mod:`repair.fallback`, :mod:`repair.budget`): past the exact repair's
time budget, or when it cannot make the model printable, a stated approximation
replaces stages 3-5 -- closed solid shells kept exactly, the other parts thickened by
eps, all united by manifold3d -- if its float32 result passes the check.

An input that is already printable comes out unchanged. :func:`repair.files.repair_file`
does the same from a mesh file to a binary STL.

Units are mm. Arrays in and out: vertices float64 (n, 3), faces int64 (m, 3). No global
state: every call is independent (the daemon runs it in a child process).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from repair.budget import Meshed, run_within_budget
from repair.check import round_to_float32
from repair.clean import Cleaned, clean_checked
from repair.deviation import max_deviation
from repair.errors import BudgetExceeded, RepairError
from repair.fallback import fallback_repair
from repair.finish import finish, unfinished_reasons
from repair.forked import Forked
from repair.hairline import without_hairline_gaps
from repair.holes import MAX_BOUNDARY_FRACTION, HolesClosed, close_small_holes
from repair.hull_and_thicken import hull_and_thicken
from repair.junk import without_internal_junk
from repair.pending_pairs import BACKGROUND_MIN_FACES
from repair.provenance import (
    carry_input_pairs,
    hull_face_sources,
    same_faces,
    starts_with_faces,
    union_face_sources,
)
from repair.report import (
    Progress,
    RepairOutcome,
    RepairTally,
    StageClock,
    input_report,
    repair_report,
)
from repair.rounding import RoundedInput, round_input
from repair.scan import scan_cleanup
from repair.stitch import stitch_cracks, without_caps
from repair.topology import EdgeTopology, edge_components, edge_topology, edge_topology_memo
from repair.union import union_of_shells, without_copies
from repair.wires import moved_segments
from repair.workers import blas_controller, cpu_workers

__all__ = ["RepairError", "RepairResult", "repair_mesh"]

#: γ of Attene's crack stitching (Sec. 5.2), as a fraction of eps: boundaries of
#: different patches closer than this are joined (:mod:`repair.stitch`).
STITCH_GAMMA = 0.25
#: How the exact path's refusal starts: the fallback is tried before it is given.
NOT_PRINTABLE = "could not make the model printable: "
#: What ``clean`` may ask for: scan cleanup when the input looks like a scan, always, never.
CLEAN_MODES = ("auto", "scan", "none")


@dataclass(frozen=True)
class RepairResult:
    """A repaired mesh (mm; float64 (n, 3) vertices exactly representable in float32,
    int64 (m, 3) faces) and its JSON-serialisable report."""

    vertices: np.ndarray
    faces: np.ndarray
    report: dict[str, Any] = field(default_factory=dict)


def repair_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    epsilon: float = 0.4,
    *,
    progress: Progress = None,
    clean: str = "auto",
    surface: str = "off",
    time_budget: float | None = None,
) -> RepairResult:
    """Repair a triangle soup into a printable solid, as exactly as possible.

    ``vertices`` (n, 3) mm, ``faces`` (m, 3) indices; ``epsilon`` (mm, > 0) is the
    thickness given to zero-thickness sheets and the diameter given to wires -- the
    printer's nozzle diameter. Solid parts are kept exactly (their outer hull); only
    sheets and wires move the surface, by at most ``0.6 * epsilon``.

    The result's coordinates are float32 values (what a binary STL stores) and it passes
    :func:`repair.check.check_printable` on them, or :class:`RepairError` is raised. The
    input is rounded to float32 first (an STL already is): solid parts come out on their
    rounded corners either way, and the arrangement then rounds once, not twice. The
    reported deviation D includes that rounding.

    ``clean``: ``"scan"`` cleans the input as a scanned mesh first (:mod:`repair.scan`),
    ``"auto"`` does when it looks like one, ``"none"`` never; the report says which.

    ``surface``: ``"holes"`` refines cylindrical and conical features to the design surface
    (chordal error within ``min(0.01, epsilon / 40)`` mm), ``"all"`` also spheres and tori,
    ``"off"`` never (:mod:`repair.surface`); the report's ``surface`` section says what.

    ``time_budget`` (seconds, optional): past it the exact repair stops and the fallback
    approximation (:mod:`repair.fallback`) is used if it can print the model; the report
    says so. The fallback is also used when the exact repair cannot make the model
    printable.
    """
    # One BLAS thread: the repair's BLAS calls are vector-sized (dot products, (n, 3) @
    # (3,) products), where waking OpenBLAS's threads costs far more than it saves
    # (np.dot of 10k doubles: 6 ms instead of 6 us on a busy machine), and one thread
    # sums in one order on any machine. Parallel work is done by forked workers.
    with blas_controller().limit(limits=1, user_api="blas"), edge_topology_memo():
        return _repair_mesh(vertices, faces, epsilon, progress, clean, surface, time_budget)


def _repair_mesh(
    vertices: np.ndarray, faces: np.ndarray, epsilon: float, progress: Progress, clean: str,
    surface: str, time_budget: float | None,
) -> RepairResult:
    eps = _checked_epsilon(epsilon)
    if clean not in CLEAN_MODES:
        raise RepairError(f"clean must be one of {', '.join(CLEAN_MODES)}, got {clean!r}")
    v_in, f_in = _checked_mesh(vertices, faces)
    if time_budget is None:
        return RepairResult(*_repair(v_in, f_in, eps, progress, clean, surface=surface))
    # The check runs here, once for both paths: a printable input needs no budget (and
    # no child), and a fallback does not check the input again.
    checked = _checked_input(v_in, f_in, progress, eps, surface, clean)
    if checked[1].verdict.ok and clean != "scan":
        return RepairResult(*_repair(v_in, f_in, eps, progress, clean, checked=checked,
                                     surface=surface))
    meshed = run_within_budget(
        lambda: _repair(v_in, f_in, eps, progress, clean, checked=checked, surface=surface),
        float(time_budget),
        lambda reason: _repair(v_in, f_in, eps, progress, clean, reason, checked, surface),
    )  # fmt: skip
    return RepairResult(*meshed)


_Checked = tuple[StageClock, RoundedInput, list | None]


def _checked_input(
    v_in: np.ndarray, f_in: np.ndarray, progress: Progress, eps: float, surface: str,
    clean: str,
) -> _Checked:
    """Stage 1 (``check_input``) on a new stage clock; with the surface features of the
    input as it comes out unchanged (or None), found in a forked child beside the check
    of a large mesh -- started first, on the CPU that the check's serial start (weld,
    native imports) leaves idle, and stopped as soon as the check says the input is not
    printable (the output is the input unchanged only when it is); an input with an edge
    not used by exactly two faces has the child stop itself after its first step."""
    clock = StageClock(progress)
    ahead: list[Forked] = []
    if surface != "off" and clean != "scan" and len(f_in) >= BACKGROUND_MIN_FACES and (
        cpu_workers() > 1
    ):
        v32 = round_to_float32(v_in)  # what round_input makes

        def features() -> list | None:
            from repair.surface.stage import features_of

            try:
                return features_of(v32, f_in, eps, surface, closed_only=True)
            except Exception:  # noqa: BLE001 -- the surface stage itself reports the failure
                return None

        ahead.append(Forked(features))

    def unwanted() -> None:
        for job in ahead:
            job.cancel()

    rounded = round_input(v_in, f_in, unwanted if ahead else None)
    found = None
    if ahead and rounded.verdict.ok:  # the input comes out unchanged
        found = ahead[0].result()
    unwanted()  # a no-op once the result was read
    clock.lap("check_input", 0.1)
    return clock, rounded, found


def _repair(
    v_in: np.ndarray, f_in: np.ndarray, eps: float, progress: Progress, clean: str,
    fallback: str | None = None, checked: _Checked | None = None, surface: str = "off",
) -> Meshed:
    """:func:`repair_mesh` of a checked input; ``fallback``: why the fallback replaces
    the exact repair (which then does not run); ``checked``: stage 1, if it ran."""
    clock, rounded, ahead = checked or _checked_input(v_in, f_in, progress, eps, surface, clean)
    if checked and fallback:
        clock.lap("exact_repair", 0.2)  # the time the exact repair was given
    if rounded.verdict.ok and clean != "scan":
        out = without_internal_junk(_unchanged(rounded))
        clock.lap("finish", 0.9)
    else:
        cleaned = clean_checked(rounded.vertices, rounded.faces, rounded.verdict)
        clock.lap("clean", 0.2)
        out = _solidify(rounded, cleaned, eps, clock, clean, fallback)
    if surface != "off":
        same = out.vertices is rounded.vertices and out.faces is rounded.faces
        out = _surface(out, eps, surface, clock, ahead if same else None)
    before = input_report(rounded.verdict, len(rounded.vertices))
    return out.vertices, out.faces, repair_report(before, out, eps, clock)


def _surface(
    out: RepairOutcome, eps: float, surface: str, clock: StageClock, found: list | None
) -> RepairOutcome:
    from repair.surface.stage import surface_stage

    try:
        out = surface_stage(out, eps, surface, found)
    except ValueError as exc:
        raise RepairError(str(exc)) from None
    clock.lap("surface", 0.95)
    return out


def _checked_epsilon(epsilon: float) -> float:
    eps = float(epsilon)
    if not np.isfinite(eps) or eps <= 0:
        raise RepairError(f"epsilon must be a positive number of mm, got {epsilon!r}")
    return eps


def _checked_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        raise RepairError("nothing printable: the mesh has no triangles")
    if not np.all(np.isfinite(v)):
        raise RepairError("vertex coordinates are not all finite")
    if f.min() < 0 or f.max() >= len(v):
        raise RepairError("face indices out of range")
    return v, f


@dataclass(frozen=True)
class _Lidded:
    """The cleaned input with its small holes closed, and all its crossing face pairs."""

    vertices: np.ndarray
    faces: np.ndarray
    pairs: np.ndarray


def _unchanged(rounded: RoundedInput) -> RepairOutcome:
    """The check proved these very float32 coordinates: no weld, no copy; D is how far
    rounding to them moved the input (0 for an STL)."""
    return RepairOutcome(rounded.vertices, rounded.faces, rounded.verdict, "unchanged",
                         rounded.rounding, RepairTally(), HolesClosed())  # fmt: skip


def _solidify(
    rounded: RoundedInput, cleaned: Cleaned, eps: float, clock: StageClock, clean: str,
    fallback: str | None = None,
) -> RepairOutcome:
    """Stages 2 (holes) to 6 (deviation) of a cleaned input that is not printable."""
    if len(cleaned.faces) == 0 and len(cleaned.segments) == 0:
        raise RepairError(
            f"nothing printable: all {len(rounded.faces)} triangles collapse to a single point"
        )
    # One sort of the edges serves the next stages while they change no face.
    topology = edge_topology(cleaned.faces)
    work_v, work_f, scan = scan_cleanup(cleaned.vertices, cleaned.faces, eps, clean, topology)
    if scan is not None and scan.topology is not None:
        topology = scan.topology  # that of the cleaned scan's faces
    clock.lap("scan_cleanup", 0.21)
    # A cracked body written twice: one copy of each patch is stitched (its slivers
    # cracked off with it, which the copy may not have, dropped first).
    work_f = without_caps(work_v, work_f, STITCH_GAMMA * eps, topology)
    work_f, cleaned = _without_copies_of(work_v, work_f, cleaned, STITCH_GAMMA * eps)
    if not topology.of(work_f):
        topology = edge_topology(work_f)
    stitched_f, stitched = stitch_cracks(work_v, work_f, STITCH_GAMMA * eps, topology)
    if len(stitched.moved) and len(cleaned.segments):
        cleaned = replace(cleaned, segments=moved_segments(cleaned.segments, work_v,
                                                           stitched.moved))  # fmt: skip
    clock.lap("stitch", 0.22)
    lidded, holes = _lidded(rounded, work_v, stitched_f, topology, scan is not None, clock)
    lidded, cleaned = _without_copies(lidded, cleaned, STITCH_GAMMA * eps)
    tally = RepairTally()
    united = None if fallback else _union_path(rounded, cleaned, lidded, eps, tally, clock)
    if united is not None:
        out, hint = united
    else:
        out, hint = _exact_or_fallback(cleaned, lidded, eps, tally, clock, fallback)
    before = out.vertices, out.faces
    out = without_hairline_gaps(without_internal_junk(out), eps)
    if out.faces is not before[1] and hint is not None:
        # Faces were removed or cut: those still on the same three points keep theirs.
        match = same_faces(*before, out.vertices, out.faces)
        hint = np.where(match >= 0, hint[np.maximum(match, 0)], -1)
    clock.lap("junk", 0.9)
    out.holes = holes
    if stitched.snapped or stitched.inserted:
        out.sections["stitched"] = stitched.to_dict()
    if scan is not None:
        out.sections["scan_cleanup"] = scan.to_dict()
    out.degenerate_removed = cleaned.degenerate_removed
    out.duplicates_removed = cleaned.duplicates_removed
    # Measured against the rounded input; the input itself is at most `rounding` away
    # from it (each rounded face lies within its corners' displacement of the original).
    # Lids that complete a planar facet are the intended surface: D is measured with them.
    reference = np.vstack([cleaned.faces, holes.exact_faces])
    out.deviation = rounded.rounding + max_deviation(
        out.vertices, out.faces, cleaned.vertices, reference, cleaned.segments,
        max_points=0 if out.path == "union" else 400_000, hint=hint,
    )  # fmt: skip
    clock.lap("deviation", 0.95)
    return out


def _lidded(
    rounded: RoundedInput, v: np.ndarray, f: np.ndarray, topology: EdgeTopology, scan: bool,
    clock: StageClock,
) -> tuple[_Lidded, HolesClosed]:
    """Stage 2: the shell's holes closed, and the crossing pairs of the result. A cleaned
    scan's holes are all closable when small against their shell, however much of its
    edges are boundary (a scan's holes are many), and get fair patches -- but a faired
    patch that crosses a face is made again as the minimal-area lid."""
    fraction = 1.0 if scan else MAX_BOUNDARY_FRACTION
    flat: tuple[int, ...] = ()
    while True:
        lidded_v, lidded_f, holes = close_small_holes(
            v, f, max_boundary_fraction=fraction, topology=topology, fair=scan, flat=flat
        )
        clock.lap("holes", 0.25)
        pairs = carry_input_pairs(rounded.vertices, rounded.faces, rounded.pairs, lidded_v,
                                  lidded_f)  # fmt: skip
        crossing = holes.faired_crossing(len(lidded_f), pairs)
        if not crossing:
            return _Lidded(lidded_v, lidded_f, pairs), holes
        flat = tuple(sorted({*flat, *crossing}))


def _without_copies(lidded: _Lidded, cleaned: Cleaned, gamma: float) -> tuple[_Lidded, Cleaned]:
    """``lidded`` and ``cleaned`` without a body written twice's copy within ``gamma``
    (mm), its crossing pairs and wires (:func:`repair.union.without_copies`)."""
    faces, pairs, segments = without_copies(
        lidded.vertices, lidded.faces, lidded.pairs, cleaned.segments, gamma
    )
    if faces is lidded.faces:
        return lidded, cleaned
    return _Lidded(lidded.vertices, faces, pairs), replace(cleaned, segments=segments)


def _without_copies_of(
    v: np.ndarray, f: np.ndarray, cleaned: Cleaned, gamma: float
) -> tuple[np.ndarray, Cleaned]:
    """``f`` without the open patches or closed shells that are copies of others within
    ``gamma`` (mm), and ``cleaned`` without their wires (:func:`repair.union.without_copies`)."""
    faces, _, segments = without_copies(v, f, np.zeros((0, 2), dtype=np.int64),
                                        cleaned.segments, gamma, patches=True)  # fmt: skip
    if faces is f:
        return f, cleaned
    return faces, replace(cleaned, segments=segments)


def _union_path(
    rounded: RoundedInput,
    cleaned: Cleaned,
    lidded: _Lidded,
    eps: float,
    tally: RepairTally,
    clock: StageClock,
) -> tuple[RepairOutcome, np.ndarray] | None:
    """The union of closed shells, finished; with, per written face, the input face it
    is believed to be a piece of (or -1). None when the path does not apply or its
    result does not pass the check."""
    v, f = lidded.vertices, lidded.faces
    union = None
    if len(cleaned.segments) == 0:
        # The input check's edge census holds for the same faces (cleaning and lids
        # changed nothing); else the union takes its own.
        same = len(f) == len(rounded.faces) and starts_with_faces(
            rounded.vertices, rounded.faces, v, f
        )
        union = union_of_shells(v, f, lidded.pairs, rounded.edge_census() if same else None)
    clock.lap("union", 0.4)
    if union is None:
        return None
    # Faces the union kept as they were keep the crossings found on them (none): only
    # the region near the cut faces and the lids' corners is tested again, where those
    # are few (counter: 7 % of 88.5k faces; box's 36 % get a whole test).
    out_v, out_f, verdict = finish(union.vertices, union.faces, eps, tally,
                                   (v, f, lidded.pairs))  # fmt: skip
    clock.lap("finish", 0.7)
    if not verdict.ok:
        return None
    # The input face each written face is a piece of, where finishing kept it (its
    # corners rounded to nearest): D bounds those without samples.
    hint = union_face_sources(cleaned.vertices, cleaned.faces, v, f, union, out_v, out_f)
    tally.intersecting_pairs = rounded.verdict.intersecting_pairs
    # Lids close holes of a shell and make no shell of their own.
    out = RepairOutcome(out_v, out_f, verdict, "union", 0.0, tally, HolesClosed(),
                        dropped_components=union.shells_dropped())  # fmt: skip
    return out, hint


def _exact_path(
    cleaned: Cleaned,
    lidded: _Lidded,
    eps: float,
    tally: RepairTally,
    clock: StageClock,
) -> tuple[RepairOutcome, np.ndarray]:
    """Exact arrangement, outer hull, thickening, finished, with the input face each
    written face is believed to be a piece of (or -1); raises :class:`RepairError`
    when nothing can be reached from outside or the result cannot be made printable."""
    # The shells of the lidded input, while the union's census of them is still memoized
    # (the hull's stages would push it out).
    shell_in = edge_components(lidded.faces) if len(lidded.faces) else None
    hull_v, hull_f, first_hull, hull_birth, united = hull_and_thicken(
        lidded.vertices, lidded.faces, eps, tally, cleaned.segments, pairs=lidded.pairs
    )
    clock.lap("hull_and_thicken", 0.6)
    dropped = 0
    if shell_in is not None:
        seen = np.unique(shell_in[hull_birth]) if len(hull_birth) else []
        dropped = int(shell_in.max()) + 1 - len(seen)
    if len(hull_f) == 0:
        raise RepairError("nothing printable: no part of the model can be reached from outside")
    # The hull keeps most faces of the lidded input (or of the bodies' union) on the
    # same points: they keep their crossing pairs; only near the others is tested.
    checked = united or (lidded.vertices, lidded.faces, lidded.pairs)
    out_v, out_f, verdict = finish(hull_v, hull_f, eps, tally, checked)
    clock.lap("finish", 0.8)
    if not verdict.ok:
        raise RepairError(NOT_PRINTABLE + "; ".join(unfinished_reasons(verdict, tally)))
    hint = hull_face_sources(cleaned.vertices, cleaned.faces, lidded.vertices, lidded.faces,
                             first_hull, hull_birth, out_v, out_f)  # fmt: skip
    return RepairOutcome(out_v, out_f, verdict, "exact", 0.0, tally, HolesClosed(),
                         dropped_components=dropped), hint  # fmt: skip


def _exact_or_fallback(
    cleaned: Cleaned, lidded: _Lidded, eps: float, tally: RepairTally, clock: StageClock,
    fallback: str | None,
) -> tuple[RepairOutcome, np.ndarray | None]:
    """The exact path (with its per-face sources, as :func:`_exact_path`); the fallback
    instead (no sources) when ``fallback`` says why, or when the exact path cannot make
    the model printable, or would take more memory than it is allowed, and the fallback
    can."""
    if fallback is None:
        try:
            return _exact_path(cleaned, lidded, eps, tally, clock)
        except BudgetExceeded as e:
            fallback = f"exact repair over its memory budget: {e}"
        except MemoryError as e:  # a native allocation failed (CGAL's std::bad_alloc)
            fallback = f"exact repair ran out of memory ({e})"
        except RepairError as e:
            if not str(e).startswith(NOT_PRINTABLE):
                raise
            fallback = str(e)
    out = fallback_repair(lidded.vertices, lidded.faces, cleaned.segments, lidded.pairs, eps,
                          fallback)  # fmt: skip
    clock.lap("fallback", 0.8)
    return out, None
