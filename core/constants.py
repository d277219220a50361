"""Numeric tolerances and physical constants, named in one place."""

#: Two vertices closer than this (metres) are the same vertex when repairing meshes.
MERGE_TOLERANCE_M = 1e-6
#: A triangle with area below this (square metres) is degenerate.
DEGENERATE_AREA_M2 = 1e-12
#: The CMU (cgspeed) BVH conversion unit: one unit is 0.056444 m (1/0.45 * 2.54 cm).
CMU_UNIT_M = 0.056444
#: Centimetres and inches in metres.
CM_M = 0.01
INCH_M = 0.0254
#: Gravity, metres per second squared, along -Y.
GRAVITY = 9.81
