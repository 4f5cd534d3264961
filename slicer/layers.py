"""Writing the planned layers as G-code, on the machine's cores.

A layer's G-code depends on the layers before it only through a small state carried from
layer to layer: where the nozzle ended (the next layer's travel ordering starts there), the
G-code writer's state and the aligned-seam tracker's. Everything else -- support and infill
paths, ordering, travel routes, the text -- is the layer's own work. So the layers are cut
into contiguous shares: the parent writes the first share while a forked worker
(slicer.parallel) writes each further one, starting one layer early (a warm-up layer, from
a guessed start) and recording the state before each of its layers. The parent then takes
over each share in order: it writes layers itself only until its own state equals the one
the worker had before the same layer -- from there the worker's text is exactly what the
parent would have written (the same function of the same state and the same layer). The
output is therefore byte-identical to a single process's, whatever the number of workers;
a wrong guess costs only the layers needed to converge (usually none: a layer's end
position rarely depends on where the nozzle entered it). Within a process, a layer made of
what an earlier one was made of (:func:`layer_keys`) and starting from the same state is
that layer's G-code again: a prism's layers and a support column are written once.
"""

from __future__ import annotations

import copy
import functools
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from slicer.errors import SliceError
from slicer.parallel import MAX_WORKERS, available_cpus, forked, parse_workers

__all__ = ["LayerRun", "Written", "layer_shares", "worker_count", "write_shares"]

#: "auto" forks no worker for a model with less estimated work (:func:`layer_work`, summed
#: over the layers) than this. Measured (bench models, one process): 5-17 µs of CPU per
#: unit, and a worker costs about 0.02 s of CPU (fork, pages copied on write, its warm-up
#: layer, its G-code sent back); 12 000 units are 0.06-0.2 s of writing, halved on two
#: cores. The 20 mm cube (5 700) stays in one process; the mushroom (19 600: most of its
#: layers repeat) writes 54 ms in the parent and 56 ms in a worker instead of 72-85 ms in
#: one process; the bunny (154 000) forks too.
AUTO_MIN_WORK = 12_000.0
#: ... and gives each worker at least half of that.
AUTO_WORK_PER_WORKER = 6_000.0
#: A writing worker's work besides its layers (:func:`layer_shares`), in layer_work units:
#: fork, pages copied on write, its warm-up layer, its G-code sent back. Measured with the
#: summary's write_cpu_seconds (9 runs each, medians, worker minus parent CPU) at 0 / 1 000 /
#: 2 000 / 3 000: mushroom +34 / +25 / 0 / +4 ms; bunny +27 / +29 / +22 / +25 ms (no trend
#: within its noise: the worker is, if anything, behind, so the bunny is not over-served).
WRITE_WORKER_OVERHEAD = 2_000.0
#: LayerRun keeps the G-code of this many layers last written or repeated, to repeat them
REPEATS_KEPT = 8
#: ... and the writing work of such a repeated layer (:func:`layer_work`): measured about
#: 30 µs of CPU per layer on the mushroom's stem, where most of them repeat
REPEAT_WORK = 7.0


@dataclass
class Written:
    """The G-code of each layer, its time (s), and the totals over the layers."""

    bodies: list[str] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)
    filament_mm: float = 0.0
    support_mm: float = 0.0
    support_seconds: float = 0.0
    #: layers a worker wrote but the parent had to write again (its start state differed)
    rewritten: int = 0
    #: processes that wrote layers (this one included); the workers' CPU seconds and
    #: largest peak resident memory (MB)
    workers: int = 1
    worker_cpu_seconds: float = 0.0
    worker_peak_mb: float = 0.0
    #: CPU seconds of writing: the parent's share (its forks included), then each worker's
    #: whole life; and the parent's wall seconds from asking for the workers' G-code to
    #: having it (its wait, unpickling included). Equal CPU and no wait: a balanced split.
    write_cpu_seconds: list[float] = field(default_factory=list)
    write_wait_seconds: float = 0.0

    def add(self, code: tuple[str, float, float, float, float]) -> None:
        """Append one layer: (text, seconds, filament mm, support mm, support seconds)."""
        text, seconds, filament, support_mm, support_s = code
        self.bodies.append(text)
        self.seconds.append(seconds + 0.1)  # Z move and layer change
        self.filament_mm += filament
        self.support_mm += support_mm
        self.support_seconds += support_s


class LayerRun:
    """Writes layers in order, carrying the state from one layer to the next."""

    def __init__(self, model: Any, profile: Any) -> None:
        from slicer.gcode import GcodeWriter
        from slicer.travel import SeamAligner

        self.model, self.profile = model, profile
        self.writer = GcodeWriter(profile)
        self.aligner = SeamAligner() if profile.seam_position == "aligned" else None
        self.pos = np.array([0.0, 0.0])
        self.support_cache: dict = {}
        self.router, self.router_key = None, None
        #: per layer, what its G-code is made of (:func:`layer_keys`); the layers written
        #: last by what they were made of and the state they started from
        self.keys = layer_keys(model, profile) if self.aligner is None else [None] * len(
            model.tops)
        self.repeats: dict[tuple, tuple] = {}

    def layer(self, i: int) -> tuple[str, float, float, float, float]:
        """Layer ``i``'s (text, seconds, filament mm, support mm, support seconds). A layer
        made of what a layer written before was made of, starting from the same state, is
        that layer's G-code again (prismatic parts, a column of support: runs of equal
        layers); it then leaves the same state."""
        key = self._repeat_key(i)
        if key is not None and key in self.repeats:
            code, pos, writer = self.repeats[key] = self.repeats.pop(key)  # now the newest
            self.pos = pos.copy()
            vars(self.writer).update(writer)
            if self.model.supports is not None:
                self.model.supports[i] = None
            return code
        code = self._write(i)
        if key is not None:
            if len(self.repeats) >= REPEATS_KEPT:
                del self.repeats[next(iter(self.repeats))]  # the oldest
            self.repeats[key] = (code, self.pos.copy(), self._writer_state())
        return code

    def _writer_state(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self.writer).items() if k != "p"}

    def _repeat_key(self, i: int) -> tuple | None:
        """Layer ``i``'s content (its key) with the state it starts from; None where
        layers are not compared (no key, or a state of unhashable values)."""
        if self.keys[i] is None:
            return None
        state = tuple((k, v.hex() if isinstance(v, float) else v)  # hex: -0.0 is not 0.0
                      for k, v in sorted(self._writer_state().items()))
        try:
            hash(state)
        except TypeError:
            return None
        return self.keys[i], self.pos.tobytes(), state

    def _write(self, i: int) -> tuple[str, float, float, float, float]:
        from slicer import geometry as geo
        from slicer.ordering import order_paths
        from slicer.planner import LayerPlan

        model, profile = self.model, self.profile
        paths = _layer_paths(model, i, profile, self.support_cache)
        plan = LayerPlan(i, float(model.tops[i]), float(model.heights[i]), paths,
                         geo.contours(model.sections[i]))
        ordered, _ = order_paths(plan.paths, self.pos, profile.seam_position, self.aligner)
        if profile.avoid_crossing_perimeters:
            from slicer.travel import TravelRouter

            key = (model.section_ids[i], model.spacing[i])
            if key != self.router_key:  # a layer like the one below keeps its router
                self.router, self.router_key = TravelRouter(model.sections[i],
                                                            model.spacing[i]), key
        code = self.writer.layer(plan, ordered, self.pos, self.router)
        self.pos = code.end_pos
        return code.text, code.seconds, code.filament_mm, code.support_mm, code.support_seconds

    def state(self) -> dict[str, Any]:
        """What the next layer's G-code depends on besides the layer itself (a copy)."""
        return copy.deepcopy({
            "pos": self.pos,
            "writer": {k: v for k, v in vars(self.writer).items() if k != "p"},
            "aligner": vars(self.aligner) if self.aligner is not None else None,
        })

    def resume(self, state: dict[str, Any]) -> None:
        """Continue from ``state`` (as :meth:`state` returned it)."""
        state = copy.deepcopy(state)
        self.pos = state["pos"]
        vars(self.writer).update(state["writer"])
        if self.aligner is not None:
            vars(self.aligner).update(state["aligner"])


def layer_keys(model: Any, profile: Any) -> list[int | None]:
    """Per layer, a number naming everything its G-code is made of besides the state it
    starts from (equal numbers, equal layers), None for the layers never compared (the
    skirt's and the brim's, and those like no other layer). A layer's paths (_layer_paths)
    are its shells (a function of its section, line width and height), its infill (of its
    shells, its solid skin, the sections below and above it, and its index's parity: the
    alternating direction), and its support; its text depends also on its index's place
    (fan off on the first layers) and, with a Z lift, its height above the bed."""
    from collections import Counter

    from slicer.geometry import shape_key

    ids = model.section_ids
    n = len(model.tops)
    lift = profile.retract_lift > 0
    first = max(profile.skirt_height, 1)
    plain = [(ids[i - 1], ids[i], ids[i + 1] if i + 1 < n else -1, model.widths[i],
              float(model.heights[i]), i % 2, i >= profile.disable_fan_first_layers,
              float(model.tops[i]) if lift else None) for i in range(first, n)]
    twice = {key for key, count in Counter(plain).items() if count > 1}
    named: dict[tuple, int] = {}
    keys: list[int | None] = [None] * n
    for i, key in enumerate(plain, start=first):
        if key not in twice:
            continue  # no other layer is like it: its regions need no comparing
        support = model.supports[i] if model.supports is not None else None
        key = (*key, shape_key(model.solids[i]),
               None if support is None else (shape_key(support.base),
                                             shape_key(support.interface), support.sheath))
        keys[i] = named.setdefault(key, len(named))
    return keys


def _layer_paths(model: Any, i: int, profile: Any, support_cache: dict) -> list:
    """Everything layer ``i`` extrudes, unordered: skirt, brim, support, shells, infill."""
    from manifold3d import CrossSection

    from slicer.planner import infill_paths, skirt_paths
    from slicer.support import support_paths

    h, width, shells = float(model.heights[i]), model.widths[i], model.shells[i]
    paths = []
    if i < profile.skirt_height:
        paths.extend(skirt_paths(profile, model.first_area, width, h))
    if i == 0:
        paths.extend(model.brim)
    if model.supports is not None:
        paths.extend(support_paths(model.supports[i], profile, width, h, support_cache))
        model.supports[i] = None
    paths.extend(shells.loops)
    paths.extend(shells.thin)
    n = len(model.tops)
    paths.extend(infill_paths(profile, i, shells.inner, model.solids[i], width, h,
                              model.sections[i - 1] if i > 0 else None,
                              model.sections[i + 1] if i + 1 < n else CrossSection()))
    return paths


def layer_work(model: Any, keys: list | None = None) -> np.ndarray:
    """Per layer, a rough measure of its writing work (about 13 µs of CPU per unit), fitted
    to CPU time per layer on the bench models (bunny, mushroom, sphere, torus; least squares
    with no negative term): its loops' vertices and a constant per loop (each island is a
    travel route), its support area at bead spacing (0.4; 0.05 where the region repeats one
    seen before, whose paths are cached) and contours, its solid skin's area at bead
    spacing, and a constant for the layer itself. (The fit gave support 0.2; 0.4 splits the
    bunny's writing evenly: 0.77 s of CPU in the parent and in the worker, 0.82 / 0.66 s
    with 0.2.) A layer whose ``keys`` entry (:func:`layer_keys`) repeats an earlier one's
    is REPEAT_WORK: its G-code is usually the earlier layer's again."""
    from slicer.geometry import shape_key

    work = np.zeros(len(model.tops))
    seen: set = set()
    repeated: set = set()
    for i, shells in enumerate(model.shells):
        key = keys[i] if keys is not None else None
        if key is not None and key in repeated:
            work[i] = REPEAT_WORK
            continue
        repeated.add(key)
        s = model.spacing[i]
        loops = shells.loops
        work[i] = (sum(len(p.points) for p in loops) + 18.0 * len(loops)
                   + 0.14 * model.solids[i].area() / s + 5.0)
        support = model.supports[i] if model.supports is not None else None
        if support is not None and not support.is_empty():
            key = (shape_key(support.base), shape_key(support.interface))
            weight = 0.05 if key in seen else 0.4
            seen.add(key)
            area = support.base.area() + support.interface.area()  # disjoint: no union
            work[i] += (weight * area / s
                        + 0.9 * (support.base.num_contour() + support.interface.num_contour()))
    return work


def worker_count(profile: Any, work: np.ndarray, *, writing: bool = True,
                 min_work: float = AUTO_MIN_WORK, per_worker: float = AUTO_WORK_PER_WORKER
                 ) -> int:
    """The profile's ``workers``; for "auto", the CPUs this process may use (at most
    MAX_WORKERS), fewer for a model with less ``work`` than ``min_work`` (then one) or
    ``per_worker`` for each, and, for ``writing`` the layers, one with aligned seams: each
    seam follows the one below it from the first layer up, so a worker cannot know where its
    layers' seams are and the parent writes them all again (planning them is not affected)."""
    try:
        asked = parse_workers(profile.workers)
    except ValueError as exc:
        raise SliceError(str(exc)) from None
    if asked is not None:
        return asked
    if writing and profile.seam_position == "aligned":
        return 1
    cpus = min(available_cpus(), MAX_WORKERS)
    total = float(work.sum())
    if cpus <= 1 or total < min_work:
        return 1
    return max(1, min(cpus, int(total // per_worker)))


def layer_shares(work: np.ndarray, workers: int, overhead: float = 0.0
                 ) -> list[tuple[int, int]]:
    """The layers cut into at most ``workers`` contiguous [begin, end) shares of about
    equal ``work``, each worker's ``overhead`` (work it does besides its layers) counted in;
    every share after the first has a layer before it (the warm-up)."""
    n = len(work)
    workers = max(1, min(workers, n // 2))
    if workers == 1:
        return [(0, n)]
    done = np.cumsum(work)
    first = (done[-1] + (workers - 1) * overhead) / workers  # the parent's share
    marks = np.arange(1, workers) * first - np.arange(workers - 1) * overhead
    cuts = np.searchsorted(done, marks) + 1
    bounds = [0, *sorted({int(c) for c in cuts if 0 < c < n}), n]
    return list(zip(bounds[:-1], bounds[1:], strict=False))


def _write_share_in_worker(run: LayerRun, begin: int, end: int) -> tuple[list, list]:
    """In a worker: layers [begin, end) after a warm-up layer, with the state before each
    and after the last."""
    run.layer(begin - 1)
    codes, states = [], []
    for i in range(begin, end):
        states.append(run.state())
        codes.append(run.layer(i))
    states.append(run.state())  # after the last layer: where the next share starts
    return codes, states


def write_shares(run: LayerRun, shares: list[tuple[int, int]], report: Any) -> Written:
    """All layers' G-code, the first share written by ``run`` here, the others by workers
    (forked now, so they see the model as it is) and taken over in order. Where no worker
    can be forked (no memory, process limit), the parent writes those shares itself."""
    n = len(run.model.tops)
    out = Written()
    jobs = [(functools.partial(_write_share_in_worker, run, begin, end),
             f"layers {begin}-{end - 1}") for begin, end in shares[1:]]
    started = time.process_time()
    with forked(jobs) as workers:
        for i in range(*shares[0]):
            out.add(run.layer(i))
            _free_layer(run.model, i)
            report("gcode", 0.5 + i / n * 0.5)
        out.write_cpu_seconds.append(time.process_time() - started)
        for k, (begin, end) in enumerate(shares[1:]):
            asked = time.monotonic()
            codes, states = workers[k].result() if k < len(workers) else ([], [])
            out.write_wait_seconds += time.monotonic() - asked
            _take_over(run, out, begin, end, codes, states)
            report("gcode", 0.5 + end / n * 0.5)
    out.workers = 1 + len(workers)
    out.write_cpu_seconds.extend(w.cpu_seconds for w in workers)
    out.worker_cpu_seconds = sum(w.cpu_seconds for w in workers)
    out.worker_peak_mb = max((w.peak_mb for w in workers), default=0.0)
    return out


def _take_over(run: LayerRun, out: Written, begin: int, end: int, codes: list,
               states: list) -> None:
    """Append layers [begin, end), which a worker wrote as ``codes`` (none: no worker):
    those before the first where the worker's start state equals ours are written again
    here; from there on its text is ours."""
    for i in range(begin, end):
        k = i - begin
        if k < len(codes) and _same(run.state(), states[k]):
            for later in codes[k:]:
                out.add(later)
            run.resume(states[-1])
            break
        out.add(run.layer(i))
        out.rewritten += k < len(codes)
    for i in range(begin, end):
        _free_layer(run.model, i)


def _free_layer(model: Any, i: int) -> None:
    model.shells[i] = model.solids[i] = None
    if model.supports is not None:
        model.supports[i] = None
    if i > 0:
        model.sections[i - 1] = None  # (section 0 stays: the skirt follows it)


def _same(a: Any, b: Any) -> bool:
    """Equal states: dicts, lists and arrays compared item by item, exactly."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)
                and a.shape == b.shape and bool(np.array_equal(a, b)))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and bool(a == b)
