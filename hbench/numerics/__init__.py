"""Numerics shared by simulation and identification: the fixed summation order and the compiled
kernels (with their numpy reference path)."""
