"""Geometry: the clamped uniform B-spline (compiled kernels), the fitter that turns polylines into
splines, and the stroke order.
"""
