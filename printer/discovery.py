"""Finding the printer: scan the serial ports, probe each with M115, keep what answers.

``[printer] port = "auto"``: the candidates are the paths matching ``SCAN_GLOBS`` in
order (``/dev/serial/by-id/*`` first: those names survive a re-plug), one per device
(a by-id link and the ``/dev/ttyACM0`` it points to are one candidate). Each is opened
at each of ``PROBE_BAUDS`` in turn and greeted the way :class:`~printer.host.PrinterHost`
always does (``M110 N0`` until an ``ok``, again after a ``start``: boards that reset
when the port opens are waited for), then asked ``M115``. The first candidate whose
M115 names a firmware is taken. Every candidate gets a one-line reason: taken, or why
not (no answer, only garbage, busy, permission denied, not a printer).

The choice is remembered (:func:`remember`, a small JSON file in the state folder) and
tried first next time, at its baud rate, so a reconnect does not re-scan every port.
"""

from __future__ import annotations

import glob
import json
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from printer.errors import (
    PortBusy,
    PortNotFound,
    PortPermission,
    PrinterDisconnected,
    PrinterError,
    PrinterTimeout,
    WrongBaud,
)

if TYPE_CHECKING:
    from printer.host import PrinterHost

SCAN_GLOBS = ("/dev/serial/by-id/*", "/dev/ttyACM*", "/dev/ttyUSB*")
PROBE_BAUDS = (115200, 250000, 230400, 57600)
PROBE_SECONDS = 3.0
REMEMBERED_FILE = "printer_port.json"

#: Errors after which trying another baud rate on the same port is pointless.
_PORT_ERRORS = (PortBusy, PortNotFound, PortPermission, PrinterDisconnected)


@dataclass(frozen=True)
class Candidate:
    """One serial port looked at. path: as found (a by-id link is kept as the link);
    device: what it resolves to; taken: the printer chosen; baud and firmware: what
    answered (None when nothing did); reason: one line saying why (not) taken."""

    path: str
    device: str
    taken: bool
    reason: str
    baud: int | None = None
    firmware: str | None = None
    answers: bool = False

    def line(self) -> str:
        """``path [-> device]: taken|not taken: reason`` (for ``preflight printer list``)."""
        where = self.path if self.device == self.path else f"{self.path} -> {self.device}"
        return f"{where}: {'taken' if self.taken else 'not taken'}: {self.reason}"

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class Discovery:
    """What a scan found. host: the chosen printer's connected host when the scan was
    asked to keep it open (the caller owns and closes it)."""

    candidates: list[Candidate] = field(default_factory=list)
    scanned: tuple[str, ...] = ()
    host: PrinterHost | None = None

    @property
    def chosen(self) -> Candidate | None:
        return next((c for c in self.candidates if c.taken), None)

    def summary(self) -> str:
        """One line: what was taken, or why nothing was."""
        chosen = self.chosen
        if chosen is not None:
            return f"found {chosen.firmware} on {chosen.path} at {chosen.baud} baud"
        if not self.candidates:
            return f"no printer found: no serial port matches {', '.join(self.scanned)}"
        why = "; ".join(c.line() for c in self.candidates)
        return f"no printer found on {len(self.candidates)} port(s): {why}"


def candidate_ports(globs: Iterable[str] = SCAN_GLOBS,
                    first: str | None = None) -> list[tuple[str, str]]:
    """(path, device) for every port matching ``globs``, in glob order (sorted within
    one glob), one per device; ``first`` (a remembered path) comes first if present."""
    paths = [first] if first and os.path.lexists(first) else []
    for pattern in globs:
        paths.extend(sorted(glob.glob(pattern)))
    seen: set[str] = set()
    out: list[tuple[str, str]] = []
    for path in paths:
        device = os.path.realpath(path)
        if device in seen:
            continue
        seen.add(device)
        out.append((path, device))
    return out


HostFactory = Callable[[str, int], "PrinterHost"]


def default_host(probe_seconds: float = PROBE_SECONDS) -> HostFactory:
    """A factory of hosts with short handshake and reply timeouts, for probing."""

    def make(path: str, baud: int) -> PrinterHost:
        from printer.host import PrinterHost

        return PrinterHost(path, baud, handshake_timeout=probe_seconds,
                           timeout=min(probe_seconds, 2.0), retries=1)

    return make


def probe(path: str, device: str, bauds: Sequence[int], make_host: HostFactory,
          keep_open: bool = False) -> tuple[Candidate, PrinterHost | None]:
    """Greet the port at each baud rate in turn; the candidate and, with ``keep_open``,
    the connected host of a port whose M115 names a firmware."""
    tried: list[str] = []
    for baud in bauds:
        host = make_host(path, baud)
        try:
            host.connect()
        except _PORT_ERRORS as exc:
            return Candidate(path, device, False, _port_reason(exc)), None
        except WrongBaud:
            tried.append(f"garbage at {baud}")
            continue
        except PrinterTimeout:
            tried.append(f"no answer at {baud}")
            continue
        except PrinterError as exc:
            tried.append(f"{baud}: {exc}")
            continue
        firmware = host.firmware
        if not firmware:
            host.close()
            return Candidate(path, device, False, f"answers at {baud} baud but its M115 names "
                             "no firmware: not a printer?", baud, None, True), None
        before = f" ({'; '.join(tried)} baud)" if tried else ""
        candidate = Candidate(path, device, False, f"{firmware} at {baud} baud{before}",
                              baud, firmware, True)
        if not keep_open:
            host.close()
            host = None
        return candidate, host
    return Candidate(path, device, False, _silent_reason(tried)), None


def _port_reason(exc: PrinterError) -> str:
    if isinstance(exc, PortBusy):
        return "busy: another program (OctoPrint, a running preflight daemon?) has it open"
    if isinstance(exc, PortPermission):
        return "permission denied: add your user to the 'dialout' group and log in again"
    if isinstance(exc, PortNotFound):
        return "gone before it could be opened (unplugged?)"
    return str(exc)


def _silent_reason(tried: list[str]) -> str:
    if tried and all(t.startswith("garbage") for t in tried):
        rates = ", ".join(t.split()[-1] for t in tried)
        return f"only garbage at {rates} baud (not a printer, or an unusual baud rate)"
    if tried and all(t.startswith("no answer") for t in tried):
        rates = ", ".join(t.split()[-1] for t in tried)
        return f"no answer to M110/M115 at {rates} baud"
    return "; ".join(tried) or "no baud rate to try"


def discover(globs: Iterable[str] = SCAN_GLOBS, bauds: Sequence[int] = PROBE_BAUDS, *,
             remembered: dict | None = None, make_host: HostFactory | None = None,
             keep_open: bool = False, scan_all: bool = False,
             progress: Callable[[str], None] | None = None) -> Discovery:
    """Scan the ports matching ``globs`` and take the first printer that answers.

    remembered: ``{"port", "baud"}`` of the last choice: tried first, at its baud rate
    first. scan_all: probe every candidate even after one was taken (for the list
    command; the others that answer are reported, not taken). keep_open: leave the
    chosen printer's host connected in ``Discovery.host``.
    """
    make_host = make_host or default_host()
    globs = tuple(globs)
    remembered = remembered or {}
    found = Discovery(scanned=globs)
    for path, device in candidate_ports(globs, remembered.get("port")):
        if found.chosen is not None and not scan_all:
            break
        order = list(bauds)
        if path == remembered.get("port") and remembered.get("baud") in order:
            order.remove(remembered["baud"])
            order.insert(0, remembered["baud"])
        if progress is not None:
            progress(f"probing {path} at {', '.join(map(str, order))} baud")
        want_open = keep_open and found.chosen is None
        candidate, host = probe(path, device, order, make_host, keep_open=want_open)
        if candidate.answers and candidate.firmware and found.chosen is None:
            candidate = replace(candidate, taken=True)
            found.host = host
        elif candidate.answers and candidate.firmware:
            candidate = replace(candidate, reason=candidate.reason +
                                f"; another printer was taken first ({found.chosen.path})")
        found.candidates.append(candidate)
    return found


def remembered_choice(state_dir: str | os.PathLike) -> dict | None:
    """The last port chosen (``{"port", "baud", "firmware"}``), or None."""
    try:
        data = json.loads((Path(state_dir) / REMEMBERED_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or not isinstance(data.get("port"), str):
        return None
    return data


def remember(state_dir: str | os.PathLike, candidate: Candidate) -> None:
    """Keep the chosen port for next time (written atomically)."""
    folder = Path(state_dir)
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / REMEMBERED_FILE
    tmp = target.with_suffix(".tmp")
    tmp.write_text(json.dumps({"port": candidate.path, "baud": candidate.baud,
                               "firmware": candidate.firmware}), encoding="utf-8")
    os.replace(tmp, target)
