"""The per-job reports: ``<name>.report.json`` (everything) and ``<name>.report.txt``
(a short human summary: what was repaired, ε and its source, slicing, print, why it failed).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from daemon.journal import Job


def _local_time(epoch: float | None) -> str:
    if not epoch:
        return "-"
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(epoch))


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "?"
    hours, rest = divmod(int(round(seconds)), 3600)
    minutes, secs = divmod(rest, 60)
    if hours:
        return f"{hours}h{minutes:02d}m"
    return f"{minutes}m{secs:02d}s" if minutes else f"{secs}s"


def report_dict(job: Job, history: list[dict[str, Any]]) -> dict[str, Any]:
    report = job.to_dict()
    report["history"] = history
    return report


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
        volume = info.get("build_volume")
        volume_text = " x ".join(f"{v:g}" for v in volume) + " mm" if volume else "unknown"
        named = job.printer not in (None, "printer")  # "printer": the one unnamed [printer]
        lines.append(f"Printer: {(str(job.printer) + ', ') if named else ''}"
                     f"{info.get('firmware') or 'unknown firmware'}, nozzle "
                     f"{info.get('nozzle_diameter')} mm (from {info.get('nozzle_source')}), "
                     f"build volume {volume_text}"
                     + (f" (from {info['build_volume_source']})"
                        if volume and info.get("build_volume_source") else ""))
    if job.epsilon is not None:
        lines.append(f"Epsilon: {job.epsilon:g} mm ({job.epsilon_source})")
    repair = job.repair_report
    if repair:
        before = repair.get("before", {}) or {}
        after = repair.get("after", {}) or {}
        verdict = repair.get("printable", {}) or {}
        ok = verdict.get("ok")
        if ok is None and isinstance(verdict, dict):
            checks = [v for v in verdict.values() if isinstance(v, bool)]
            ok = all(checks) if checks else None
        lines.append(f"Repair: {repair.get('summary', '')}".rstrip())
        lines.append(f"  triangles {before.get('triangles', '?')} -> {after.get('triangles', '?')}"
                     f", max deviation {_number(repair.get('deviation'))} mm, volume "
                     f"{_number(repair.get('volume'))} mm3, printable: "
                     f"{'yes' if ok else ('no' if ok is False else '?')}")
        from repair.surface.stage import feature_lines

        lines += feature_lines(repair.get("surface"))
    elif job.kind == "gcode":
        lines.append("Repair/slicing: skipped (G-code file), checked against the build volume "
                     "and the command policy")
    sliced = job.slice_summary
    if sliced:
        lines.append(f"Slicing: {sliced.get('layers', '?')} layers, filament "
                     f"{_number(sliced.get('filament_mm'), 1000, 'm')} "
                     f"({_number(sliced.get('filament_g'))} g), "
                     f"estimated {_duration(sliced.get('estimated_seconds'))}")
        if sliced.get("support_cm3") or sliced.get("brim"):
            lines.append(f"  support {_number(sliced.get('support_cm3'))} cm3, "
                         f"{_duration(sliced.get('support_seconds'))} of the print"
                         + (", with a brim" if sliced.get("brim") else ""))
        turned = sliced.get("orientation") or {}
        if turned.get("rotated"):  # the daemon turned the model ([profile] orient)
            lines.append(f"  turned {_number(turned.get('angle_deg'))}° about "
                         f"{turned.get('axis')}: {turned.get('reason', '')}")
    printed = job.print_result
    if printed:
        lines.append(f"Print: {printed.get('acked_lines', '?')} of "
                     f"{printed.get('total_lines', '?')} lines acknowledged in "
                     f"{_duration(printed.get('seconds'))}"
                     + (f" - {printed['error']}" if printed.get("error") else ""))
    if history:
        lines.append("Timeline: " + ", ".join(f"{step['to_state']} {_local_time(step['at'])}"
                                              for step in history))
    return "\n".join(lines) + "\n"


def _number(value: Any, divisor: float = 1.0, unit: str = "") -> str:
    """A measure in 3 significant digits; a dict measure shows its "max" (or "value")."""
    if isinstance(value, dict):
        value = value.get("max", value.get("value"))
    if isinstance(value, (int, float)):
        return f"{value / divisor:.3g}{(' ' + unit) if unit else ''}"
    return "?"


def report_paths(folder: Path, stem: str) -> tuple[Path, Path]:
    """Where ``write_reports`` puts a job's JSON and text reports."""
    return folder / f"{stem}.report.json", folder / f"{stem}.report.txt"


def write_reports(folder: Path, stem: str, job: Job, history: list[dict[str, Any]]
                  ) -> tuple[Path, Path]:
    """Write ``<stem>.report.json`` and ``<stem>.report.txt`` into ``folder`` atomically."""
    from repair.io import write_atomic  # not at import time: it brings numpy along

    folder.mkdir(parents=True, exist_ok=True)
    json_path, text_path = report_paths(folder, stem)
    write_atomic(json_path, [json.dumps(report_dict(job, history), indent=2,
                                        default=str).encode()])
    write_atomic(text_path, [report_text(job, history).encode()])
    return json_path, text_path
