"""The nerfstudio method ``cinesplat``: splatfacto + a distilled 3-dim CLIP latent per Gaussian.

Importing this package registers the numpy safe globals torch>=2.6 needs to load nerfstudio
checkpoints with ``weights_only=True`` (compat.py explains why this import happens before any
``torch.load`` in stock ns-render / ns-viewer) and puts the environment's ``ffmpeg`` script on PATH when none is
there (ffmpeg_entry.ensure_on_path: ns-render's mp4 without a system ffmpeg). Kept import-light: nerfstudio / gsplat /
open_clip are imported only by the submodules that need them, so ``relevancy``, ``semantic_scene`` and
``checkpoint`` work without them.
"""

from __future__ import annotations

from cinenerf_ns.ffmpeg_entry import ensure_on_path
from cinenerf_ns.method.compat import register_torch_safe_globals

register_torch_safe_globals()
ensure_on_path()  # stock ns-render checks for ffmpeg after loading this method: the venv's own ffmpeg script
