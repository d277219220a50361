"""Geometry and data for the garment studio: no training, no GUI.

Pure functions on numpy arrays with small frozen records between stages. Importing ``core``
must stay cheap and headless: heavy libraries (open3d, newton, torch) are imported inside the
functions that need them.
"""
