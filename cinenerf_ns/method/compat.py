"""nerfstudio 1.1.5 compatibility shims for current torch / offline machines.

1. torch >= 2.6 defaults ``torch.load(weights_only=True)``. nerfstudio's ``eval_setup`` (ns-render,
   ns-viewer, ns-eval) and the trainer's resume path call ``torch.load(path, map_location="cpu")``
   without ``weights_only=False``, and a stock nerfstudio checkpoint holds numpy float64 scalars
   (``ExponentialDecayScheduler``'s lambda returns ``np.exp(...)`` so ``LambdaLR._last_lr`` is a list
   of numpy scalars). Unpickling them needs ``numpy._core.multiarray.scalar`` and the numpy dtype
   classes, which are not on torch's allow-list -> ``UnpicklingError``.
   Fix, two layers:
   * ``register_torch_safe_globals()`` adds exactly those numpy reconstructors to the allow-list. It runs
     on ``import cinenerf_ns.method``. The chain that guarantees it runs before ``torch.load`` in stock
     ``eval_setup``: ``yaml.load(config.yml, Loader=yaml.Loader)`` constructs our config dataclasses
     (``!!python/object:cinenerf_ns.method.model.CineSplatModelConfig``), which imports
     ``cinenerf_ns.method.model`` -> ``cinenerf_ns.method/__init__`` -> this module; the
     ``torch.load`` of the checkpoint comes after (eval_utils.eval_load_checkpoint). ns-train's
     ``--load-dir`` resume path imports the method entry point before the trainer exists.
   * cinesplat's own optimiser schedules use ``schedulers.FloatExponentialDecayScheduler`` whose lambda
     returns a python float, so a cinesplat checkpoint holds no numpy scalars in the first place.

2. Offline LPIPS. splatfacto's ``populate_modules`` builds torchmetrics' LPIPS, whose constructor
   downloads torchvision's AlexNet weights; without network the model cannot be constructed.
   ``offline_safe_lpips()`` patches the LPIPS class that ``populate_modules`` imports with a factory that
   builds the real metric when the weights are cached (or downloadable, with a short timeout) and
   otherwise returns ``UnavailableLPIPS`` (returns NaN; cinesplat drops the key from its metrics) after
   ONE warning per process.
"""

from __future__ import annotations

import contextlib
import os
import socket
import warnings
from typing import Iterator, List

import numpy as np
import torch

_SAFE_GLOBALS_DONE = False


def numpy_safe_globals() -> List[object]:
    """The numpy callables/classes a pickled numpy scalar or dtype references."""
    out: List[object] = []
    try:  # numpy >= 2
        from numpy._core.multiarray import scalar as _scalar  # type: ignore
    except ImportError:  # pragma: no cover - numpy 1.x
        from numpy.core.multiarray import scalar as _scalar  # type: ignore
    out.append(_scalar)
    out.append(np.dtype)
    # numpy >= 1.25 pickles dtypes through their concrete classes (np.dtypes.Float64DType ...)
    dtypes_mod = getattr(np, "dtypes", None)
    if dtypes_mod is not None:
        for name in dir(dtypes_mod):
            obj = getattr(dtypes_mod, name)
            if isinstance(obj, type) and issubclass(obj, np.dtype):
                out.append(obj)
    out.append(np.ndarray)
    try:
        from numpy._core.multiarray import _reconstruct  # type: ignore
    except ImportError:  # pragma: no cover
        from numpy.core.multiarray import _reconstruct  # type: ignore
    out.append(_reconstruct)
    return out


def register_torch_safe_globals() -> bool:
    """Allow nerfstudio checkpoints (numpy scalars in scheduler state) under ``weights_only=True``.

    Idempotent. Returns False on torch versions without ``add_safe_globals`` (< 2.4: nothing needed).
    """
    global _SAFE_GLOBALS_DONE
    if _SAFE_GLOBALS_DONE:
        return True
    add = getattr(torch.serialization, "add_safe_globals", None)
    if add is None:  # pragma: no cover - old torch loads with weights_only=False by default
        return False
    add(numpy_safe_globals())
    _SAFE_GLOBALS_DONE = True
    return True


# ----------------------------------------------------------------------------------------------
# offline LPIPS
# ----------------------------------------------------------------------------------------------
_LPIPS_WARNED = False
ALEXNET_WEIGHTS = "alexnet-owt-7be5be79.pth"


class UnavailableLPIPS(torch.nn.Module):
    """Stand-in for torchmetrics LPIPS when its AlexNet weights cannot be had: returns NaN."""

    available = False

    def forward(self, *args, **kwargs) -> torch.Tensor:  # noqa: D401
        return torch.tensor(float("nan"))


def lpips_weights_cached() -> bool:
    """True when torchvision's AlexNet weights (what torchmetrics' LPIPS loads) are in the hub cache."""
    return os.path.exists(os.path.join(torch.hub.get_dir(), "checkpoints", ALEXNET_WEIGHTS))


def _warn_once(msg: str) -> None:
    global _LPIPS_WARNED
    if _LPIPS_WARNED:
        return
    _LPIPS_WARNED = True
    try:
        from nerfstudio.utils.rich_utils import CONSOLE

        CONSOLE.print(f"[bold yellow]WARNING: {msg}")
    except Exception:  # pragma: no cover
        warnings.warn(msg)


def make_lpips(mode: str = "auto", download_timeout_s: float = 5.0, **kwargs) -> torch.nn.Module:
    """Build torchmetrics' LPIPS if its weights are available, else ``UnavailableLPIPS`` (one warning).

    mode: "auto" (cached weights -> real metric; else try a download with a short socket timeout),
    "cached" (never touch the network), "off" (always the stand-in, no warning).
    """
    if mode == "off":
        return UnavailableLPIPS()
    from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity as _LPIPS

    kwargs.setdefault("normalize", True)
    if not lpips_weights_cached() and mode == "cached":
        _warn_once(
            "LPIPS disabled: torchvision AlexNet weights not in "
            f"{os.path.join(torch.hub.get_dir(), 'checkpoints', ALEXNET_WEIGHTS)} (no download attempted). "
            "Eval metrics omit 'lpips'. Copy the file there to enable it."
        )
        return UnavailableLPIPS()
    old = socket.getdefaulttimeout()
    try:
        socket.setdefaulttimeout(download_timeout_s)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return _LPIPS(**kwargs)
    except Exception as e:  # network-less: URLError / socket.gaierror / timeout / HTTP errors
        _warn_once(
            f"LPIPS disabled: AlexNet weights unavailable ({type(e).__name__}: {str(e)[:120]}). "
            f"Eval metrics omit 'lpips'. To enable, place {ALEXNET_WEIGHTS} in "
            f"{os.path.join(torch.hub.get_dir(), 'checkpoints')}."
        )
        return UnavailableLPIPS()
    finally:
        socket.setdefaulttimeout(old)


@contextlib.contextmanager
def offline_safe_lpips(mode: str = "auto") -> Iterator[None]:
    """Within the block, ``torchmetrics.image.lpip.LearnedPerceptualImagePatchSimilarity(...)`` (the name
    splatfacto's ``populate_modules`` imports) builds through ``make_lpips``."""
    import torchmetrics.image.lpip as lpip_mod

    orig = lpip_mod.LearnedPerceptualImagePatchSimilarity

    def factory(*args, **kwargs):
        if args:
            raise TypeError("offline_safe_lpips: positional LPIPS arguments are not supported")
        return make_lpips(mode, **kwargs)

    lpip_mod.LearnedPerceptualImagePatchSimilarity = factory  # type: ignore[assignment]
    try:
        yield
    finally:
        lpip_mod.LearnedPerceptualImagePatchSimilarity = orig  # type: ignore[assignment]


# ------------------------------------------------------------------------------------------------
# 3. Seed point clouds without open3d.
# nerfstudio's NerfstudioDataParser reads `ply_file_path` (splatfacto's initial points) with open3d,
# which has no wheels for Python 3.12 / many machines; the import then crashes the whole run. The
# patched reader uses the project's .ply reader (planner.ply) when open3d is missing and applies exactly the
# transform nerfstudio applies (homogeneous `@ transform_matrix.T`, then `*= scale_factor`).
_PLY_PATCHED = False


def read_ply_points(path) -> tuple[torch.Tensor, torch.Tensor]:
    """(xyz [P, 3] float32, rgb [P, 3] uint8) of a point-cloud .ply (ascii or binary); rgb is grey when
    the file has no colour."""
    from cinenerf_ns.planner.scene.ply import read_ply_vertices

    v = read_ply_vertices(path)
    xyz = np.stack([np.asarray(v[k], dtype=np.float32) for k in ("x", "y", "z")], axis=1)  # [P, 3]
    names = v.dtype.names or ()
    if all(c in names for c in ("red", "green", "blue")):
        rgb = np.stack([np.asarray(v[c]) for c in ("red", "green", "blue")], axis=1)
        rgb = (rgb * 255.0).round() if rgb.dtype.kind == "f" and rgb.max() <= 1.0 else rgb
        rgb = np.clip(rgb, 0, 255).astype(np.uint8)
    else:
        rgb = np.full((len(xyz), 3), 128, np.uint8)
    return torch.from_numpy(xyz), torch.from_numpy(rgb)


def patch_ply_loader_without_open3d() -> bool:
    """Make NerfstudioDataParser read `ply_file_path` with read_ply_points when open3d is not importable.
    Returns True when the patch is (already) installed. A no-op for machines with open3d."""
    global _PLY_PATCHED
    if _PLY_PATCHED:
        return True
    try:
        from nerfstudio.data.dataparsers.nerfstudio_dataparser import Nerfstudio
    except Exception:  # nerfstudio not installed: nothing to patch
        return False
    orig = Nerfstudio._load_3D_points

    def _load_3D_points(self, ply_file_path, transform_matrix, scale_factor):
        try:
            import open3d  # noqa: F401
        except ImportError:
            xyz, rgb = read_ply_points(ply_file_path)
            if len(xyz) == 0:
                return None
            xyz = torch.cat((xyz, torch.ones_like(xyz[..., :1])), -1) @ transform_matrix.T
            return {"points3D_xyz": xyz * scale_factor, "points3D_rgb": rgb}
        return orig(self, ply_file_path, transform_matrix, scale_factor)

    Nerfstudio._load_3D_points = _load_3D_points
    _PLY_PATCHED = True
    return True
