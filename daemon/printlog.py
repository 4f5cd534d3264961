"""What a print leaves behind besides its job state: temperature samples and their
summary (:class:`TemperatureLog`), readings as text, and the stream's result as a dict."""

from __future__ import annotations

import logging
import time
from typing import Any

log = logging.getLogger("preflight.printer")


class TemperatureLog:
    """The stream's temperature callback for one job: live readings in the printer
    status (``preflight status``, the web page), one sample every
    ``SAMPLE_SECONDS`` into the journal (a soft write), and a summary for the report."""

    SAMPLE_SECONDS = 10.0

    def __init__(self, link: Any, job_id: int) -> None:
        self.link = link
        self.job_id = job_id
        self.last_sample = -float("inf")
        self.samples = 0
        self.peak: dict[str, float] = {}

    def __call__(self, readings: dict[str, tuple[float, float | None]]) -> None:
        live = {heater: [round(cur, 1), target] for heater, (cur, target) in readings.items()}
        self.link._set_status(temperatures=live)
        for heater, (current, _target) in readings.items():
            self.peak[heater] = max(self.peak.get(heater, current), current)
        now = time.monotonic()
        if now - self.last_sample >= self.SAMPLE_SECONDS:
            self.last_sample = now
            self.samples += 1
            try:
                self.link.journal.add_temperatures(self.job_id, live)
            except Exception:  # a busy journal must not stop the print
                log.exception("recording temperatures")

    def summary(self) -> dict[str, Any]:
        return {"samples": self.samples,
                "peak": {heater: round(value, 1) for heater, value in self.peak.items()}}


_HEATER_NAMES = {"T": "hotend", "B": "bed", "C": "chamber"}


def format_temperatures(temps: dict[str, Any] | None) -> str | None:
    """``{"T": [120.3, 210.0], "B": [41.0, 60.0]}`` -> ``"hotend 120.3/210 °C, bed
    41.0/60 °C"``; None when there is nothing to show."""
    if not temps:
        return None
    parts = []
    for heater, (current, target) in sorted(temps.items(), key=lambda kv: kv[0] != "T"):
        name = _HEATER_NAMES.get(heater, heater)
        parts.append(f"{name} {current:.1f}" + (f"/{target:g}" if target is not None else "")
                     + " °C")
    return ", ".join(parts)


def result_dict(result: Any) -> Any:
    if result is None:
        return None
    if hasattr(result, "to_dict"):
        return result.to_dict()
    if hasattr(result, "__dataclass_fields__"):
        import dataclasses

        return {k: v for k, v in dataclasses.asdict(result).items()
                if isinstance(v, (int, float, str, bool, type(None)))}
    return str(result)
