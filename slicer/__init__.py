"""Embedded slicer: a closed mesh (mm) in, Marlin-flavoured G-code out."""
