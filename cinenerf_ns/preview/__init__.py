"""See the shot: CPU preview renders (mp4, contact sheet, GIF) of a nerfstudio camera path through a splat.

    from cinenerf_ns.preview import preview_camera_path
    out = preview_camera_path(load_splat("scene.npz").params, camera_path_dict, "renders", name="shot")
    out["paths"]["mp4"], out["paths"]["contact_sheet"], out["timings"]["total_s"]

Frames come from the compiled tile rasteriser (native/raster.c), else the pure-torch tiled renderer
(raster_torch.py), or gsplat on CUDA (device="cuda"). No nerfstudio, gsplat or viser import at module level.

The public names below load their module on first use (PEP 562): `cinesplat-preview --help` and its option errors
need only cli.py and cameras.py, not torch.
"""
from __future__ import annotations

from cinenerf_ns.planner.lazy_exports import lazy_exports

_WHERE = {
    "PreviewCameras": "cameras", "path_cameras": "cameras", "viewmat_from_c2w": "cameras",
    "preview_camera_path": "preview",
    "PreviewScene": "raster_torch", "make_scene": "raster_torch", "raster_reference": "raster_torch",
    "NERFSTUDIO_BACKGROUND": "render", "render_frame": "render", "scene_from_splat": "render",
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _WHERE)
