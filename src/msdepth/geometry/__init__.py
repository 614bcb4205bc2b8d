"""Geometry shared by losses, networks and evaluation: warping, cameras, disparity and depth."""
