"""Reconstruction: slices registered in 3D, pipes tracked across them, fitted and completed (pure numpy)."""
