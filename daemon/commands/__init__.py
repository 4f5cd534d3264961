"""Sub-commands of the ``preflight`` CLI.

Each module here holds one group of sub-commands and exposes
``register(subparsers) -> None``, which adds its parsers and sets
``func=<callable(args) -> int>`` on each. Modules keep heavy imports (numpy,
trimesh, manifold3d) inside the command functions so that ``preflight --help``
and the daemon's start-up stay fast.
"""

import sys


def fail(message: str, code: int = 1) -> int:
    """Print ``preflight: MESSAGE`` on stderr; return the exit status ``code``."""
    print(f"preflight: {message}", file=sys.stderr)
    return code
