"""STEP in (the optional ``cad`` extra): Open CASCADE reads the exact B-rep and tessellates it
at the printer's chordal tolerance, so curved features (holes, bosses) are only as far from
their design surface as the printer can tell.

Open CASCADE comes from ``cadquery-ocp`` (``pip install 'preflight[cad]'``); without it a STEP
file is refused with a one-line reason that says how to install it. The tessellation is
Open CASCADE's ``BRepMesh_IncrementalMesh``: every triangle corner lies on the exact surface
and no point of a facet is farther than the chordal (linear) deflection from it, nor does
a facet turn by more than :data:`ANGULAR_DEFLECTION` from its neighbour. Open CASCADE writes
the triangulation as a binary STL (C++ throughout, no per-triangle Python), whose corners are
then welded exactly: BRepMesh discretises each B-rep edge once for both faces that share it,
so the welded shell is closed. Coordinates pass through float32 there, as they do in every
STL this daemon writes (about 4e-6 mm at 100 mm).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from repair.io.base import STEP_SUFFIXES as STEP_SUFFIXES  # where callers have looked for it
from repair.io.base import Mesh, MeshReadError, finish, sniff_foreign
from repair.io.stl import read_stl

#: Largest chordal deflection (mm) of the tessellation; a finer nozzle lowers it (nozzle/40).
MAX_CHORDAL_DEFLECTION = 0.01
NOZZLE_DIVISOR = 40.0

#: Angular deflection (radians, about 29 degrees; Open CASCADE's own default) between
#: neighbouring facets. At printer scale the chordal deflection is the one that binds; this
#: one only keeps a tiny pin at a dozen facets or more (2 pi / 0.5).
ANGULAR_DEFLECTION = 0.5

INSTALL_HINT = "pip install 'preflight[cad]'"
MISSING_KERNEL = (
    "STEP files need the optional CAD kernel (Open CASCADE), which is not installed; "
    f"install it with: {INSTALL_HINT}"
)
#: The wheel links the system's OpenGL and X11 client libraries (not bundled by manylinux);
#: a headless system may lack them.
SYSTEM_LIBRARIES = "apt-get install libgl1 libx11-6"

#: Every STEP (ISO 10303-21) file starts with this line.
STEP_MAGIC = b"ISO-10303-21"


def chordal_deflection(nozzle: float | None = None) -> float:
    """The tessellation's chordal deflection (mm) for a printer with this nozzle diameter
    (mm): ``min(0.01, nozzle / 40)``; 0.01 mm when the nozzle is not known."""
    if nozzle is None or not nozzle > 0:
        return MAX_CHORDAL_DEFLECTION
    return min(MAX_CHORDAL_DEFLECTION, float(nozzle) / NOZZLE_DIVISOR)


def read_step(
    path: Path, name: str, *, deflection: float | None = None, max_triangles: int | None = None
) -> Mesh:
    """Read a STEP file into a closed, welded :class:`Mesh` in millimetres.

    ``deflection`` is the chordal deflection in mm (default :func:`chordal_deflection`).
    The file's own length unit (inch, metre, ...) is converted to mm by Open CASCADE, which
    does not say what it was, so ``unit_scale`` stays 1.0. Raises
    :class:`MeshReadError` (one line) when Open CASCADE is missing, the file is not STEP,
    holds no surface, or cannot be tessellated.
    """
    _check_header(path, name)
    linear = chordal_deflection() if deflection is None else float(deflection)
    if not linear > 0:
        raise MeshReadError(f"{name}: the chordal deflection must be > 0 mm, got {deflection!r}")
    try:
        from OCP.BRepMesh import BRepMesh_IncrementalMesh
        from OCP.IFSelect import IFSelect_RetDone
        from OCP.STEPControl import STEPControl_Reader
        from OCP.StlAPI import StlAPI_Writer
        from OCP.TopAbs import TopAbs_FACE
        from OCP.TopExp import TopExp_Explorer
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.split(".")[0] != "OCP":
            raise MeshReadError(f"{name}: {_unloadable(exc)}") from None
        raise MeshReadError(f"{name}: {MISSING_KERNEL}") from None
    except ImportError as exc:
        raise MeshReadError(f"{name}: {_unloadable(exc)}") from None
    _quiet_kernel()
    reader = STEPControl_Reader()
    if reader.ReadFile(str(path)) != IFSelect_RetDone:
        raise MeshReadError(f"{name}: not a readable STEP file (Open CASCADE refused it)")
    reader.SetSystemLengthUnit(1.0)  # millimetres, whatever the file's unit
    if reader.TransferRoots() == 0:
        raise MeshReadError(f"{name}: the STEP file holds no shape that can be transferred")
    shape = reader.OneShape()
    if shape.IsNull() or not TopExp_Explorer(shape, TopAbs_FACE).More():
        raise MeshReadError(f"{name}: the STEP file holds no surface or solid to print")
    mesher = BRepMesh_IncrementalMesh(shape, linear, False, ANGULAR_DEFLECTION, False)
    if not mesher.IsDone():
        raise MeshReadError(f"{name}: Open CASCADE could not tessellate the STEP model")
    with tempfile.TemporaryDirectory(prefix="preflight-step-") as tmp:
        stl = Path(tmp) / "tessellated.stl"
        writer = StlAPI_Writer()
        writer.ASCIIMode = False
        if not writer.Write(shape, str(stl)) or not stl.exists():
            raise MeshReadError(f"{name}: a face of the STEP model could not be tessellated")
        soup = read_stl(stl.read_bytes(), name, max_triangles)
    return finish(soup.vertices, soup.faces, "step", name)


def _unloadable(exc: ImportError) -> str:
    return (f"the CAD kernel (Open CASCADE) is installed but cannot load ({exc}); "
            f"its system libraries: {SYSTEM_LIBRARIES}")


def _check_header(path: Path, name: str) -> None:
    try:
        with open(path, "rb") as fh:
            head = fh.read(512)
    except OSError as exc:
        raise MeshReadError(f"{name}: cannot read: {exc.strerror or exc}") from None
    if STEP_MAGIC not in head.removeprefix(b"\xef\xbb\xbf")[:64]:
        foreign = sniff_foreign(head[:16])
        raise MeshReadError(
            f"{name}: not a STEP file" + (f", it is {foreign}" if foreign else
                                          " (no ISO-10303-21 header)")
        )


def _quiet_kernel() -> None:
    """Open CASCADE prints its reader's statistics and warnings to stdout; a daemon's stdout
    is not the place, and what matters reaches the user as the MeshReadError. Only alarms
    (the kernel's own crashes) are printed."""
    from OCP.Message import Message, Message_Gravity

    printers = Message.DefaultMessenger_s().Printers()
    for i in range(printers.Lower(), printers.Upper() + 1):
        printers.Value(i).SetTraceLevel(Message_Gravity.Message_Alarm)
