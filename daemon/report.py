"""The per-job reports: ``<name>.report.json`` (everything) and ``<name>.report.txt``
(a short human summary: what was repaired, ε and its source, slicing, print, why it failed).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from daemon.journal import Job


def _ts(t: float | None) -> str:
    if not t:
        return "-"
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t))


def _duration(s: float | None) -> str:
    if s is None:
        return "?"
    s = int(round(s))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}h{m:02d}m" if h else (f"{m}m{sec:02d}s" if m else f"{sec}s")


def report_dict(job: Job, history: list[dict[str, Any]]) -> dict[str, Any]:
    d = job.to_dict()
    d["history"] = history
    return d


def report_text(job: Job, history: list[dict[str, Any]]) -> str:
    """A few lines a person reads on the share: outcome first, then the details."""
    lines = [f"preflight job {job.id}: {job.source_name}"]
    outcome = {
        "done": "PRINTED",
        "failed": "FAILED",
        "cancelled": "CANCELLED",
        "interrupted": "INTERRUPTED",
    }.get(str(job.state), str(job.state).upper())
    lines.append(f"Result: {outcome}" + (f" - {job.reason}" if job.reason else ""))
    info = job.printer_info or {}
    if info:
        bv = info.get("build_volume")
        bvs = " x ".join(f"{v:g}" for v in bv) + " mm" if bv else "unknown"
        lines.append(f"Printer: {info.get('firmware') or 'unknown firmware'}, nozzle "
                     f"{info.get('nozzle_diameter')} mm (from {info.get('nozzle_source')}), "
                     f"build volume {bvs}")
    if job.epsilon is not None:
        lines.append(f"Epsilon: {job.epsilon:g} mm ({job.epsilon_source})")
    rep = job.repair_report
    if rep:
        before = rep.get("before", {}) or {}
        after = rep.get("after", {}) or {}
        pr = rep.get("printable", {}) or {}
        ok = pr.get("ok")
        if ok is None and isinstance(pr, dict):
            bools = [v for v in pr.values() if isinstance(v, bool)]
            ok = all(bools) if bools else None
        lines.append(f"Repair: {rep.get('summary', '')}".rstrip())
        lines.append(f"  triangles {before.get('triangles', '?')} -> {after.get('triangles', '?')}"
                     f", max deviation {_fmt(rep.get('deviation'))} mm, volume "
                     f"{_fmt(rep.get('volume'))} mm3, printable: "
                     f"{'yes' if ok else ('no' if ok is False else '?')}")
    elif job.kind == "gcode":
        lines.append("Repair/slicing: skipped (G-code file), checked against the build volume "
                     "and the command policy")
    s = job.slice_summary
    if s:
        lines.append(f"Slicing: {s.get('layers', '?')} layers, filament "
                     f"{_fmt(s.get('filament_mm'), 1000, 'm')} ({_fmt(s.get('filament_g'))} g), "
                     f"estimated {_duration(s.get('estimated_seconds'))}")
    p = job.print_result
    if p:
        lines.append(f"Print: {p.get('acked_lines', '?')} of {p.get('total_lines', '?')} lines "
                     f"acknowledged in {_duration(p.get('seconds'))}"
                     + (f" - {p['error']}" if p.get("error") else ""))
    if history:
        lines.append("Timeline: " + ", ".join(f"{h['to_state']} {_ts(h['at'])}" for h in history))
    return "\n".join(lines) + "\n"


def _fmt(v: Any, div: float = 1.0, unit: str = "") -> str:
    if isinstance(v, dict):
        v = v.get("max", v.get("value"))
    if isinstance(v, (int, float)):
        return f"{v / div:.3g}{(' ' + unit) if unit else ''}"
    return "?"


def write_reports(folder: Path, stem: str, job: Job, history: list[dict[str, Any]]
                  ) -> tuple[Path, Path]:
    """Write ``<stem>.report.json`` and ``<stem>.report.txt`` into ``folder`` atomically."""
    folder.mkdir(parents=True, exist_ok=True)
    jp = folder / f"{stem}.report.json"
    tp = folder / f"{stem}.report.txt"
    from repair.io import write_atomic  # not at import time: it brings numpy along

    for path, text in ((jp, json.dumps(report_dict(job, history), indent=2, default=str)),
                       (tp, report_text(job, history))):
        write_atomic(path, [text.encode()])
    return jp, tp
