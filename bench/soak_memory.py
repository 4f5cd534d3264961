"""The daemon's resident memory over the soak: start, end, max and the trend.

Samples from the first ``warmup`` seconds of each daemon start are left out of the
trend (imports, caches, the first jobs). The memory counts as flat when the median of
the last quarter of the remaining samples is within max(10 MB, 20 %) of the median of
the first quarter; with fewer than 8 such samples there is not enough to judge.
"""

from __future__ import annotations

import statistics
from typing import Any

from soak_procs import Sample

GROWTH_MB = 10.0
GROWTH_FRACTION = 0.2


def _slope_mb_per_hour(samples: list[Sample]) -> float | None:
    if len(samples) < 2:
        return None
    xs = [s.at for s in samples]
    ys = [s.kb / 1024 for s in samples]
    mx, my = statistics.fmean(xs), statistics.fmean(ys)
    var = sum((x - mx) ** 2 for x in xs)
    if var == 0:
        return None
    return 3600 * sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / var


def memory_figures(samples: list[Sample], *, warmup: float) -> dict[str, Any]:
    """Figures (MB) of the daemon's RSS samples, and whether it stayed flat."""
    if not samples:
        return {"samples": 0}
    mb = [s.kb / 1024 for s in samples]
    settled = [s for s in samples if s.age >= warmup]
    out: dict[str, Any] = {
        "samples": len(samples), "start_mb": round(mb[0], 1), "end_mb": round(mb[-1], 1),
        "max_mb": round(max(mb), 1), "settled_samples": len(settled),
    }
    lives: dict[int, list[Sample]] = {}
    for s in settled:
        lives.setdefault(s.life, []).append(s)
    if lives:
        longest = max(lives.values(), key=lambda ss: ss[-1].age - ss[0].age)
        slope = _slope_mb_per_hour(longest)
        out["longest_life_minutes"] = round(longest[-1].age / 60, 1)
        out["longest_life_mb"] = [round(longest[0].kb / 1024, 1),
                                  round(longest[-1].kb / 1024, 1)]
        out["longest_life_trend_mb_per_hour"] = None if slope is None else round(slope, 2)
    if len(settled) < 8:
        out["flat"] = None  # not enough settled samples to judge
        return out
    quarter = max(2, len(settled) // 4)
    early = statistics.median(s.kb / 1024 for s in settled[:quarter])
    late = statistics.median(s.kb / 1024 for s in settled[-quarter:])
    slope = _slope_mb_per_hour(settled)
    out.update(settled_start_mb=round(early, 1), settled_end_mb=round(late, 1),
               trend_mb_per_hour=None if slope is None else round(slope, 2),
               flat=late - early <= max(GROWTH_MB, GROWTH_FRACTION * early))
    return out
