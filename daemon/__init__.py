"""preflight daemon: spool watching, job journal, pipeline orchestration, CLI.

The only package that imports the others: it calls ``repair``, then ``slicer``,
then ``printer``.
"""

__version__ = "0.1.0"
