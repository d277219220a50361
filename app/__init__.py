"""The command line (``dng``) and the Open3D desktop studio. Nothing in core/ or training/ imports this."""
