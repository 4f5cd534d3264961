"""The issue-19 design plate (tests/repair/plate_model.py) as exact B-rep, written as STEP by
Open CASCADE itself (the optional ``cad`` extra): what a CAD program would export."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from plate_model import BOSS_CENTRE, BOSS_HEIGHT, BOSS_RADIUS, HOLES, PLATE_SIZE


def write_plate_step(
    path: Path,
    *,
    size: Sequence[float] = PLATE_SIZE,
    holes: Sequence[Sequence[float]] = HOLES,
    boss: tuple[float, float, float, float] | None = (*BOSS_CENTRE, BOSS_RADIUS, BOSS_HEIGHT),
    unit: str = "MM",
) -> Path:
    """Write the plate (box ``size`` at the origin, through-holes ``(x, y, r)``, a boss
    ``(x, y, r, height)`` on its top face) to ``path`` as STEP in length ``unit`` (``"MM"``,
    ``"INCH"``, ...). Needs OCP."""
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Cut, BRepAlgoAPI_Fuse
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox, BRepPrimAPI_MakeCylinder
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    def cylinder(x: float, y: float, z: float, r: float, h: float):
        axis = gp_Ax2(gp_Pnt(x, y, z), gp_Dir(0.0, 0.0, 1.0))
        return BRepPrimAPI_MakeCylinder(axis, r, h).Shape()

    sx, sy, sz = size
    part = BRepPrimAPI_MakeBox(sx, sy, sz).Shape()
    if boss is not None:
        bx, by, br, bh = boss
        part = BRepAlgoAPI_Fuse(part, cylinder(bx, by, sz - 1.0, br, bh + 1.0)).Shape()
    for x, y, r in holes:
        part = BRepAlgoAPI_Cut(part, cylinder(x, y, -1.0, r, sz + 2.0)).Shape()
    Interface_Static.SetCVal_s("write.step.unit", unit)
    try:
        writer = STEPControl_Writer()
        writer.Transfer(part, STEPControl_AsIs)
        status = writer.Write(str(path))
    finally:
        Interface_Static.SetCVal_s("write.step.unit", "MM")
    assert status == IFSelect_RetDone, f"Open CASCADE could not write {path}"
    return path
