"""See the shot: CPU preview renders (mp4, contact sheet, GIF) of a nerfstudio camera path through a splat.

    from cinenerf_ns.preview import preview_camera_path
    out = preview_camera_path(load_splat("scene.npz").params, camera_path_dict, "renders", name="shot")
    out["paths"]["mp4"], out["paths"]["contact_sheet"], out["timings"]["total_s"]

Frames come from the compiled tile rasteriser (native/raster.c), else the pure-torch tiled renderer
(raster_torch.py), or gsplat on CUDA (device="cuda"). No nerfstudio, gsplat or viser import at module level.
"""
from .cameras import PreviewCameras, path_cameras, viewmat_from_c2w
from .preview import preview_camera_path
from .raster_torch import PreviewScene, make_scene, raster_reference
from .render import NERFSTUDIO_BACKGROUND, render_frame, scene_from_splat

__all__ = [
    "NERFSTUDIO_BACKGROUND", "PreviewCameras", "PreviewScene", "make_scene", "path_cameras", "preview_camera_path",
    "render_frame", "raster_reference", "scene_from_splat", "viewmat_from_c2w",
]
