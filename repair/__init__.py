"""Mesh I/O and as-exact-as-possible repair (Attene 2018).

Pure functions: ``(vertices, faces)`` arrays in, arrays or small frozen
dataclasses out. Units are millimetres. Imports neither ``slicer`` nor ``printer``.
"""
