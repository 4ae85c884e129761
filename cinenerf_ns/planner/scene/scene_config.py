"""How a splat's Gaussians become obstacles: the settings, without torch (the command lines check them before
loading anything heavy)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

DEFAULT_SAFETY_MARGIN = 0.01  # extra distance kept from every ellipsoid on top of the camera radius (CLI and viewer)


@dataclass
class SceneConfig:
    """How splat parameters become obstacles."""

    beta: float = 2.0
    """Confidence multiple of sigma: semi-axes = beta * opacity * exp(log_scale) (paper Sec. V: 2)."""
    camera_radius: float = 0.03
    """Radius of the camera body sphere, in scene units (nerfstudio's normalised units; paper: 0.03)."""
    opacity_floor: float = 0.05
    """Gaussians with opacity below this are not obstacles."""
    min_axis: float = 1e-4
    """Semi-axes are clamped up to this length (flat Gaussians stay valid, slightly conservative)."""
    max_axis: Optional[float] = None
    """Gaussians with a semi-axis longer than this are dropped as floaters (None: keep all)."""

    @classmethod
    def with_margin(cls, camera_radius: Optional[float] = None, safety_margin: float = DEFAULT_SAFETY_MARGIN,
                    **kwargs) -> "SceneConfig":
        """The obstacle model shots are planned with: the camera sphere (default radius: ``camera_radius``'s field
        default) grown by ``safety_margin``, as cinesplat-plan and the viewers plan (a splat only approximates the
        surfaces). Other fields from ``kwargs``."""
        radius = cls.camera_radius if camera_radius is None else camera_radius
        return cls(camera_radius=radius + safety_margin, **kwargs)
