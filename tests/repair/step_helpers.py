"""STEP test helpers: the issue-19 design plate (tests/repair/plate_model.py) as exact B-rep,
written as STEP by Open CASCADE itself (what a CAD program would export), and a Python
environment in which the optional ``cad`` extra is absent."""

from __future__ import annotations

import os
import sys
import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from plate_model import BOSS_CENTRE, BOSS_HEIGHT, BOSS_RADIUS, HOLES, PLATE_SIZE  # noqa: E402

from repair.io.step import INSTALL_HINT  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def _ocp_loads() -> bool:
    try:
        from OCP.STEPControl import STEPControl_Reader  # noqa: F401
    except ImportError:
        return False
    return True


HAVE_OCP = _ocp_loads()
NO_OCP = f"the optional cad extra (cadquery-ocp) is not installed: {INSTALL_HINT}"
needs_ocp = pytest.mark.skipif(not HAVE_OCP, reason=NO_OCP)
#: float32 rounding of coordinates up to 60 mm (the tessellation passes through binary STL)
F32 = 8e-6

#: A sitecustomize that hides OCP from the interpreter it runs in (and the processes that
#: interpreter starts with its environment): as if the extra were not installed ("absent"),
#: or as the dynamic loader fails when a system library is missing ("unloadable").
HIDE_OCP = textwrap.dedent('''
    import sys

    class _NoCadExtra:
        def find_spec(self, name, path=None, target=None):
            if name == "OCP" or name.startswith("OCP."):
                if MODE == "absent":
                    raise ModuleNotFoundError(f"No module named {name!r}", name=name)
                raise ImportError("libGL.so.1: cannot open shared object file: No such file "
                                  "or directory")
            return None

    sys.meta_path.insert(0, _NoCadExtra())
''')


def without_cad_extra_env(tmp: Path, mode: str = "absent") -> dict[str, str]:
    """Environment for a subprocess (and its children) in which ``import OCP`` fails:
    ``mode`` "absent" (not installed) or "unloadable" (a system library is missing)."""
    site = tmp / f"no_cad_extra_{mode}"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(f"MODE = {mode!r}\n" + HIDE_OCP)
    path = [str(site), str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]
    return dict(os.environ, PYTHONPATH=os.pathsep.join(path))


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


def facet_sagitta(v: np.ndarray, f: np.ndarray, x: float, y: float, r: float):
    """(sagitta of each side facet of the cylinder (x, y, r), the distinct angles of its
    corners): a side facet has all corners on the cylinder, at two heights (a cap's facets lie
    at one). The sagitta is r minus the exact smallest distance from the axis to the facet
    (the cylinder is vertical, so that is a 2D point-to-triangle distance)."""
    on = np.abs(np.hypot(v[:, 0] - x, v[:, 1] - y) - r) < 1e-4
    facets = f[on[f].all(axis=1) & (np.ptp(v[f][:, :, 2], axis=1) > 1e-6)]
    tri = v[facets][:, :, :2] - np.array([x, y])  # (m, 3, 2), axis at the origin
    a, b = tri, np.roll(tri, -1, axis=1)
    ab = b - a
    t = np.clip(-(a * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300), 0.0, 1.0)
    nearest = np.hypot(*(a + t[..., None] * ab).transpose(2, 0, 1)).min(axis=1)
    angles = np.unique(np.round(np.arctan2(v[on, 1] - y, v[on, 0] - x), 6))
    return r - nearest, len(angles)
