"""One step of the dual active-set method of Goldfarb & Idnani (Math. Programming 27, 1983) with Hessian I: face p
into the working set. Shared by the goal's projection (search/goal.py, 3 variables) and the corridor QP
(trajectory/dual_qp.py, 3n variables); their compiled ports (native/project.c, native/dual_qp.c) repeat these decisions.

x is the projection of the target onto the working set's faces (held with equality) with multipliers u >= 0. Adding a
violated face p moves x along z, the part of -a_p off the working set's span, while the working set's multipliers
change by -s r; a multiplier reaching 0 first (ratio test) drops its face and the step goes on (partial step), else
the face is met (full step) and joins. The objective only grows, so faces cannot cycle in exact arithmetic. Empty
feasible set (Farkas): a_p lies in the span of the working set's faces and no multiplier can shrink.
"""
from __future__ import annotations

from typing import List, Optional, Tuple

import numpy as np


def add_face(A: np.ndarray, b: np.ndarray, row2: np.ndarray, p: int, x: np.ndarray, W: List[int], u: np.ndarray,
             it: int, max_iter: int) -> Tuple[np.ndarray, np.ndarray, int, Optional[str]]:
    """Face p of A x <= b (A [F, d], b [F], row2 [F] = |A_f|^2) into the working set W (mutated) with multipliers
    u [|W|]: -> (x [d], u, steps taken so far, None when it joined, else "infeasible" or "unfinished": max_iter steps,
    or rounding left face p met after a partial step). A singular working set raises np.linalg.LinAlgError."""
    up = 0.0  # multiplier of the face being added
    a = A[p]
    while True:
        it += 1
        if it > max_iter:
            return x, u, it, "unfinished"
        if W:
            N = A[W]  # [k, d]
            r = np.linalg.solve(N @ N.T, N @ a)  # [k]  du_W = -s r per unit of u_p
            z = N.T @ r - a  # [d]  dx per unit of u_p: minus a's part off the span of the working set
        else:
            r, z = np.zeros(0), -a
        zz = float(z @ z)
        dependent = zz <= 1e-18 * float(row2[p])
        pos = np.flatnonzero(r > 1e-12 * (1.0 + np.abs(r).max(initial=0.0)))
        t1, k = np.inf, -1
        if pos.size:
            ratios = u[pos] / r[pos]
            j = int(np.argmin(ratios))
            t1, k = float(ratios[j]), int(pos[j])
        t2 = np.inf if dependent else float(a @ x - b[p]) / zz
        if not np.isfinite(t1) and not np.isfinite(t2):
            return x, u, it, "infeasible"  # a nonnegative combination of the working set's faces and face p
        if t2 < 0:
            return x, u, it, "unfinished"  # rounding: face p no longer violated after a partial step
        s = min(t1, t2)
        if np.isfinite(t2):
            x = x + s * z
        u = u - s * r
        up += s
        if s == t2:  # full step: face p joins the working set
            W.append(p)
            return x, np.append(u, up), it, None
        W.pop(k)  # partial step: face k's multiplier reached 0, it leaves
        u = np.delete(u, k)
