"""A smooth curve through the corridor: Bezier QP, timing, dynamics and look-at orientation.

Modules: bezier, dynamics, orientation, qp, timing.
"""
