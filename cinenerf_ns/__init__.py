"""cinenerf_ns: generative cinematography for nerfstudio (Cine-NeRF).

Sub-packages:
  planner/    collision tests, safe corridors, trajectories, camera paths (no nerfstudio/gsplat/viser)
  method/     the nerfstudio method ``cinesplat`` (splatfacto + distilled CLIP latents)
  viewer/     the cinematography panel (nerfstudio viewer and standalone viser viewer)
  synthetic/  ground-truth rooms for evaluation and the bundled demo scene
"""

__version__ = "0.1.0"
