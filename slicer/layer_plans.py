"""Planning the layers' shells and solid skins on the machine's cores.

A layer's shells (perimeter loops, thin walls, the region left for infill) depend only on
its own section, and its solid skin only on its infill region and its neighbours' sections,
which every process has once the model is sliced. So the layers are cut into contiguous
shares: forked workers (slicer.parallel) plan each share after the first while the parent
plans the first, and each sends its layers back as arrays -- paths as they are, regions as
their contours. Every layer, the parent's own included, takes the same way back (contours,
then a CrossSection built from them), so what is planned is the same, byte for byte,
whatever the number of workers. Only what must see every layer (support, from the top
down) stays in the parent, after this.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import numpy as np
from manifold3d import CrossSection, FillRule

from slicer.parallel import forked

__all__ = ["plan_shells_and_skins", "plan_work"]

#: Planning work per vertex: measured 5-6 µs of CPU per vertex of the bunny's, the
#: sphere's and the torus's sections (0.3-0.8 s of planning on one process).
PLAN_UNIT = 0.3

#: "auto" plans in one process below this much work (:func:`plan_work`), and gives each
#: worker at least PLAN_WORK_PER_WORKER. Measured (one process vs two, CPU of each): a
#: planning worker costs 0.02-0.06 s of CPU (fork, pages copied on write, its layers sent
#: back) and takes half the parent's planning: 6 000 units (a 12 mm sphere, 0.09 s) saved
#: the parent 0.02 s for 0.05 s more CPU; 18 000 (a 20k-triangle sphere, 0.21 s) saved 0.11 s.
PLAN_MIN_WORK = 10_000.0
PLAN_WORK_PER_WORKER = 5_000.0

#: A layer as it travels between processes: (loops, thin walls, infill region's contours,
#: solid skin's contours).
Portable = tuple[list, list, list[np.ndarray], list[np.ndarray]]


def plan_work(sections: list, perimeters: int, spacing: list[float],
              ids: list[int] | None = None) -> np.ndarray:
    """Per layer, its expected planning work before anything is planned (15-21 µs of CPU
    per unit on the bench models): PLAN_UNIT for each vertex of its perimeter loops (about
    the section's, per loop) and of its area at bead spacing; a layer like one below it
    (prismatic parts) costs next to nothing: its plan is shared. ``ids``: the sections'
    geometry.shape_ids, where already known."""
    from slicer.geometry import shape_ids

    ids = shape_ids(sections) if ids is None else ids
    seen: set = set()
    work = np.full(len(sections), 5.0)
    for i, section in enumerate(sections):
        if ids[i] not in seen:
            seen.add(ids[i])
            work[i] += PLAN_UNIT * (section.num_vert() * max(perimeters, 1)
                                    + 0.05 * section.area() / spacing[i])
    return work


def _region(contours: list[np.ndarray]) -> CrossSection:
    return CrossSection(contours, FillRule.Positive) if contours else CrossSection()


def _plan_share(model: Any, profile: Any, begin: int, end: int) -> list[Portable]:
    """Shells and solid skins of layers [begin, end), as arrays. Identical layers
    (prismatic parts) share their shells."""
    from slicer import geometry as geo
    from slicer.planner import plan_shells, skin_regions

    n = len(model.tops)
    planned: dict = {}
    shells = []
    for i in range(begin, end):
        h = float(model.heights[i])
        key = (model.section_ids[i], model.widths[i], h)
        if key not in planned:
            planned[key] = plan_shells(model.sections[i], model.widths[i], h,
                                       profile.perimeters, profile.thin_walls,
                                       profile.resolution)
        shells.append(planned[key])
    empty = CrossSection()
    inner = [empty] * n  # the other layers' regions are not needed: skins look at sections
    inner[begin:end] = [s.inner for s in shells]
    solids = skin_regions(inner, model.sections, profile.top_layers, profile.bottom_layers,
                          model.spacing, profile.infill_percent >= 100, model.section_ids)
    outlines: dict[int, list[np.ndarray]] = {}  # a region shared by layers, outlined once

    def outline(region: CrossSection) -> list[np.ndarray]:
        if id(region) not in outlines:
            outlines[id(region)] = geo.contours(region)
        return outlines[id(region)]

    return [(s.loops, s.thin, outline(s.inner), outline(solids[i]))
            for i, s in zip(range(begin, end), shells, strict=True)]


def _adopt(model: Any, begin: int, planned: list[Portable], template: Any) -> None:
    """Put a share's planned layers into the model, regions rebuilt from their contours
    (once for contours shared by layers: the same list, pickled once)."""
    built: dict[int, tuple[list, CrossSection]] = {}

    def region(contours: list[np.ndarray]) -> CrossSection:
        if id(contours) not in built:  # the list is kept with it: its id is not reused
            built[id(contours)] = (contours, _region(contours))
        return built[id(contours)][1]

    for k, (loops, thin, inner, solid) in enumerate(planned):
        model.shells[begin + k] = dataclasses.replace(template, loops=loops, thin=thin,
                                                      inner=region(inner))
        model.solids[begin + k] = region(solid)


def plan_shells_and_skins(model: Any, profile: Any, report: Any) -> None:
    """Fill ``model.shells`` and ``model.solids`` for every layer, on the profile's
    ``workers`` (slicer.layers.worker_count; this process included, fewer where no worker
    can be forked). A worker that fails is a SliceError naming it; none outlives this."""
    from slicer.layers import layer_shares, worker_count

    n = len(model.tops)
    work = plan_work(model.sections, profile.perimeters, model.spacing, model.section_ids)
    shares = layer_shares(work, worker_count(profile, work, writing=False,
                                             min_work=PLAN_MIN_WORK,
                                             per_worker=PLAN_WORK_PER_WORKER))
    model.shells, model.solids = [None] * n, [None] * n
    jobs = [(functools.partial(_plan_share, model, profile, begin, end),
             f"planning layers {begin}-{end - 1}") for begin, end in shares[1:]]
    with forked(jobs) as workers:
        report("shells", 0.2)
        template = _template(model, profile)
        # its own layers are adopted before waiting: the workers finish meanwhile
        _adopt(model, 0, _plan_share(model, profile, *shares[0]), template)
        for k, (begin, end) in enumerate(shares[1:]):
            _adopt(model, begin, workers[k].result() if k < len(workers)
                   else _plan_share(model, profile, begin, end), template)
            report("shells", 0.2 + end / n * 0.25)
    model.plan_workers = 1 + len(workers)
    model.plan_worker_cpu_seconds = sum(w.cpu_seconds for w in workers)
    model.plan_worker_peak_mb = max((w.peak_mb for w in workers), default=0.0)


def _template(model: Any, profile: Any) -> Any:
    """An empty shells object of the planner's type, for dataclasses.replace."""
    from slicer.planner import plan_shells

    return plan_shells(CrossSection(), model.widths[0], float(model.heights[0]), 0, False,
                       profile.resolution)
