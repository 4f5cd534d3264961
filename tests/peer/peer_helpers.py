"""The OctoPrint peer for tests and the bench: its venv, the bridge process, the test
file, and what the peer's record says it accepted and ran."""

from __future__ import annotations

import json
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PEER_VENV = ROOT / ".venv-peer"
BRIDGE = Path(__file__).with_name("octoprint_bridge.py")
#: How CI (.ci/run) builds the peer venv.
PEER_INSTALL = "python3 -m venv .venv-peer && .venv-peer/bin/pip install 'OctoPrint==1.11.*'"
WAITS = {"M190": "M140", "M109": "M104"}


def peer_python() -> Path | None:
    """The peer venv's python, or None when the venv is absent (or has no OctoPrint)."""
    python = PEER_VENV / "bin" / "python"
    if not python.exists():
        return None
    found = list((PEER_VENV / "lib").glob("python3*/site-packages/octoprint/plugins/"
                                           "virtual_printer/virtual.py"))
    return python if found else None


def start_bridge(link: Path, record: Path | None = None,
                 settings: dict | None = None) -> subprocess.Popen:
    """OctoPrint's VirtualPrinter on a pty linked at ``link`` (its own process)."""
    python = peer_python()
    if python is None:
        raise RuntimeError(f"no OctoPrint peer venv; build it with: {PEER_INSTALL}")
    command = [str(python), str(BRIDGE), "--link", str(link),
               "--settings", json.dumps(settings or {})]
    if record is not None:
        command += ["--record", str(record)]
    errors = Path(str(link) + ".stderr")
    with open(errors, "wb") as sink:
        proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=sink, text=True)
    first = proc.stdout.readline().strip()
    if not first.startswith("/dev/"):
        proc.kill()
        proc.wait()
        raise RuntimeError(f"the OctoPrint bridge did not start: {errors.read_text()[-2000:]}")
    return proc


def stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def sliced_commands(count: int = 2000) -> list[str]:
    """The first ``count`` commands the embedded slicer writes for a 20 mm cube, its
    heat-up waits (M190/M109, another lane's test) turned into set-and-go (M140/M104)."""
    from printer.gcode import clean_lines
    from slicer.engine import slice_file
    from slicer.profile import Profile

    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "cube.gcode"
        slice_file(ROOT / "tests" / "data" / "cube_20mm.3mf", out,
                   Profile.for_printer().with_overrides({"layer_height": 0.3}))
        commands = clean_lines(out.read_text().splitlines())
    commands = [WAITS.get(c.split()[0], c.split()[0]) + c[len(c.split()[0]):]
                for c in commands]
    if len(commands) < count:
        raise RuntimeError(f"the sliced cube has only {len(commands)} commands")
    return commands[:count]


@dataclass
class PeerRecord:
    """What the peer's record says. accepted: line numbers in the order its counter took
    them; executed: line number -> the commands it ran as that line; silent: lines it
    accepted without running them; unnumbered: commands it ran that came without a
    line number (the host's handshake and queries)."""

    accepted: list[int] = field(default_factory=list)
    executed: dict[int, list[str]] = field(default_factory=dict)
    unnumbered: list[str] = field(default_factory=list)
    resets: int = 0

    @property
    def silent(self) -> list[int]:
        return [n for n in self.accepted if n not in self.executed]


def read_record(path: Path) -> PeerRecord:
    record = PeerRecord()
    for raw in path.read_text().splitlines():
        kind, _, rest = raw.partition(" ")
        if kind == "A":
            record.accepted.append(int(rest))
        elif kind == "R":
            record.resets += 1
        elif kind == "X":
            number, _, command = rest.partition(" ")
            if number.isdigit():
                record.executed.setdefault(int(number), []).append(command)
            else:
                record.unnumbered.append(command)
    return record


def lines_per_second(count: int, seconds: float) -> float:
    return count / seconds if seconds > 0 else float("inf")


