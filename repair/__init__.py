"""Mesh I/O and as-exact-as-possible repair (Attene 2018).

Pure functions: ``(vertices, faces)`` arrays in, arrays or small frozen
dataclasses out. Units are millimetres. Imports neither ``slicer`` nor ``printer``.
"""

import os as _os

# libigl runs its exact arrangement in threads and then emits new vertices and faces in
# thread order; the repair's tie-breaks (which sliver vertex survives a collapse, which
# pieces a mend re-arranges) follow that order, so the same file could repair
# differently -- or fail -- from one run to the next. One thread makes it reproducible
# (measured: identical output on repeated runs; about 10-30 % slower libigl calls).
# Set IGL_NUM_THREADS yourself to trade that back.
_os.environ.setdefault("IGL_NUM_THREADS", "1")
