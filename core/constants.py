"""Numeric tolerances and physical constants, named in one place."""

#: Two vertices closer than this (metres) are the same vertex when repairing meshes.
MERGE_TOLERANCE_M = 1e-6
#: Welding for the simulation: vertices closer than this fraction of the mesh's bounding-box
#: diagonal are one vertex (UV seams split in a file are joined; the cloth's own vertices are
#: millimetres apart, this is micrometres for a garment).
WELD_TOLERANCE_REL = 1e-5
#: A triangle with area below this (square metres) is degenerate.
DEGENERATE_AREA_M2 = 1e-12
#: The CMU (cgspeed) BVH conversion unit: one unit is 0.056444 m (1/0.45 * 2.54 cm).
CMU_UNIT_M = 0.056444
#: Centimetres and inches in metres.
CM_M = 0.01
INCH_M = 0.0254
#: Gravity, metres per second squared, along -Y.
GRAVITY = 9.81
