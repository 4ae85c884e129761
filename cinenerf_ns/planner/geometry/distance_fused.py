"""One-kernel (Triton, CUDA only) version of ``distance._distance_local``: signed point-ellipsoid distance.

Why: the eager torch version runs Newton + bisection rounds over the whole batch, each round ~45 kernel launches and
one host sync, ~30-60 rounds per call: on a GPU that is launch- and sync-bound (candidate scoring at 1M Gaussians;
docs/PLANNER_DEFAULTS.md has the numbers). Here each lane solves its own pair in registers: one launch, no sync.

Same algorithm, term for term, as ``distance._distance_local`` (Eberly's scaled root finding, the degenerate s = -1
branch, bracket + safeguarded Newton). The only difference: a lane stops updating once its own bracket has converged
(the eager loop keeps refining converged pairs until the whole batch is done), so results agree to rounding, not
bit for bit (GPU test: |diff| <= 1e-12 x scale). ``_distance_local`` uses this on CUDA tensors and falls back to
the eager loop when Triton is missing or fails.
"""
from __future__ import annotations

import warnings

import torch
from torch import Tensor

_FAILED = False


try:  # Triton ships with CUDA builds of torch; without it the eager loop is used
    import triton
    import triton.language as tl

    HAVE_TRITON = True
except Exception:  # noqa: BLE001
    HAVE_TRITON = False

if HAVE_TRITON:
    @triton.jit
    def _g(s, z0, z1, z2, r0, r1, r2, p0, p1, p2):
        q0 = tl.where(p0, r0 * z0 / (s + r0), 0.0)
        q1 = tl.where(p1, r1 * z1 / (s + r1), 0.0)
        q2 = tl.where(p2, r2 * z2 / (s + r2), 0.0)
        g = q0 * q0 + q1 * q1 + q2 * q2 - 1.0
        dg = -2.0 * (q0 * q0 / (s + r0) + q1 * q1 / (s + r1) + q2 * q2 / (s + r2))
        return g, dg

    @triton.jit
    def _swap_desc(ea, ya, eb, yb):
        sw = eb > ea
        return tl.where(sw, eb, ea), tl.where(sw, yb, ya), tl.where(sw, ea, eb), tl.where(sw, ya, yb)

    @triton.jit
    def _kernel(W, R, OUT, n, max_iter, BLOCK: tl.constexpr):
        offs = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
        m = offs < n
        y0 = tl.abs(tl.load(W + offs * 3 + 0, mask=m, other=1.0))
        y1 = tl.abs(tl.load(W + offs * 3 + 1, mask=m, other=1.0))
        y2 = tl.abs(tl.load(W + offs * 3 + 2, mask=m, other=1.0))
        e0 = tl.load(R + offs * 3 + 0, mask=m, other=1.0)
        e1 = tl.load(R + offs * 3 + 1, mask=m, other=1.0)
        e2 = tl.load(R + offs * 3 + 2, mask=m, other=1.0)
        # e0 >= e1 >= e2 (sorting network), |w| follows its axis
        e0, y0, e1, y1 = _swap_desc(e0, y0, e1, y1)
        e1, y1, e2, y2 = _swap_desc(e1, y1, e2, y2)
        e0, y0, e1, y1 = _swap_desc(e0, y0, e1, y1)
        z0 = y0 / e0
        z1 = y1 / e1
        z2 = y2 / e2
        inside = (z0 * z0 + z1 * z1 + z2 * z2) < 1.0
        r0 = (e0 / e2) * (e0 / e2)
        r1 = (e1 / e2) * (e1 / e2)
        r2 = (e2 / e2) * (e2 / e2)
        p0 = z0 > 0.0
        p1 = z1 > 0.0
        p2 = z2 > 0.0
        pole = (p0 & (r0 <= 1.0)) | (p1 & (r1 <= 1.0)) | (p2 & (r2 <= 1.0))
        rz0 = tl.where(p0 & (r0 > 1.0), r0 * z0 / tl.maximum(r0 - 1.0, 1e-300), 0.0)
        rz1 = tl.where(p1 & (r1 > 1.0), r1 * z1 / tl.maximum(r1 - 1.0, 1e-300), 0.0)
        rz2 = tl.where(p2 & (r2 > 1.0), r2 * z2 / tl.maximum(r2 - 1.0, 1e-300), 0.0)
        g_m = rz0 * rz0 + rz1 * rz1 + rz2 * rz2 - 1.0
        degenerate = (pole == 0) & (g_m <= 0.0)
        neg_inf = float("-inf")
        lo = tl.maximum(tl.maximum(tl.where(p0, r0 * (z0 - 1.0), neg_inf), tl.where(p1, r1 * (z1 - 1.0), neg_inf)),
                        tl.where(p2, r2 * (z2 - 1.0), neg_inf))
        lo = tl.maximum(lo, -1.0)
        hi = -1.0 + tl.sqrt((r0 * z0) * (r0 * z0) + (r1 * z1) * (r1 * z1) + (r2 * z2) * (r2 * z2))
        hi = tl.maximum(hi, lo)
        work = (degenerate == 0) & (p0 | p1 | p2)
        lo = tl.where(work, lo, 0.0)
        hi = tl.where(work, hi, 0.0)
        done = (work == 0) | (m == 0)
        for _ in range(max_iter):
            g_lo, dg_lo = _g(lo, z0, z1, z2, r0, r1, r2, p0, p1, p2)
            newton = lo - g_lo / dg_lo
            mid = 0.5 * (lo + hi)
            g_mid, _d = _g(mid, z0, z1, z2, r0, r1, r2, p0, p1, p2)
            lo2 = tl.where(g_mid > 0.0, mid, lo)
            hi2 = tl.where(g_mid > 0.0, hi, mid)
            ok = ((newton - newton) == 0.0) & (newton > lo2) & (newton < hi2)  # finite and inside the bracket
            g_nt, _d2 = _g(tl.where(ok, newton, lo2), z0, z1, z2, r0, r1, r2, p0, p1, p2)
            lo2 = tl.where(ok & (g_nt >= 0.0), newton, lo2)
            hi2 = tl.where(ok & (g_nt < 0.0), newton, hi2)
            now = ((hi2 - lo2) <= 1e-15 * (1.0 + tl.abs(hi2))) | (tl.abs(newton - lo) <= 1e-15 * (1.0 + tl.abs(lo)))
            lo = tl.where(done, lo, lo2)
            hi = tl.where(done, hi, hi2)
            done = done | now
        s = lo
        x0 = tl.where(p0, e0 * r0 * z0 / (s + r0), 0.0)
        x1 = tl.where(p1, e1 * r1 * z1 / (s + r1), 0.0)
        x2 = tl.where(p2, e2 * r2 * z2 / (s + r2), 0.0)
        xd0 = e0 * rz0
        xd1 = e1 * rz1
        rest = tl.maximum(1.0 - (xd0 / e0) * (xd0 / e0) - (xd1 / e1) * (xd1 / e1) - rz2 * rz2, 0.0)
        x0 = tl.where(degenerate, xd0, x0)
        x1 = tl.where(degenerate, xd1, x1)
        x2 = tl.where(degenerate, e2 * tl.sqrt(rest), x2)
        d = tl.sqrt((x0 - y0) * (x0 - y0) + (x1 - y1) * (x1 - y1) + (x2 - y2) * (x2 - y2))
        tl.store(OUT + offs, tl.where(inside, -d, d), mask=m)


def available(t: Tensor) -> bool:
    """True when ``t`` is a CUDA tensor and the kernel can be (or was) built."""
    return HAVE_TRITON and not _FAILED and t.is_cuda


def distance_local_fused(w: Tensor, radii: Tensor, max_iter: int = 200, block: int = 128) -> Tensor:
    """Signed distance [...] from local points w [..., 3] (float64, CUDA) to axis-aligned ellipsoids with semi-axes
    radii [..., 3] centred at the origin; see ``distance._distance_local``. Raises on any Triton failure (the caller
    falls back)."""
    shape = w.shape[:-1]
    wf = w.reshape(-1, 3).contiguous().double()
    rf = radii.reshape(-1, 3).contiguous().double()
    n = wf.shape[0]
    out = torch.empty(n, dtype=torch.float64, device=w.device)
    if n:
        _kernel[(triton.cdiv(n, block),)](wf, rf, out, n, int(max_iter), BLOCK=block)
    return out.reshape(shape)


def disable(reason: BaseException) -> None:
    """Stop using the fused kernel in this process (after a failure), with one warning."""
    global _FAILED
    if not _FAILED:
        warnings.warn(f"fused distance kernel unavailable ({type(reason).__name__}: {reason}); using the eager "
                      f"torch loop", RuntimeWarning, stacklevel=3)
    _FAILED = True
