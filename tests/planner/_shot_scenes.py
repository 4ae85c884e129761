"""Hand-built test scene for shot ranking: a floor, a target ball and a tall wall on one side of it."""
import numpy as np
import torch

from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene

TARGET = np.array([0.5, 0.0, 0.3])
TARGET_RADIUS = 0.08
GO_TO = np.array([0.5, 0.0, 0.62])


def _discs(centres, normals, size):
    """Flat ellipsoids (semi-axes size, size, size/10) lying on planes with the given unit normals."""
    n = len(centres)
    z = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(z[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]]))
    x = np.cross(helper, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    rot = np.stack([x, y, z], axis=2)  # columns = axes
    radii = np.tile([size, size, size / 10], (n, 1))
    return centres, rot, radii


def walled_target_scene(camera_radius: float = 0.03) -> EllipsoidScene:
    """Floor z=0 over [-1,1]^2, a ball of radius TARGET_RADIUS at TARGET, and a wall x=0 spanning
    y in [-0.8, 0.8], z in [0, 1]: the half-space x < 0 looks at the target through the wall."""
    g = np.linspace(-1, 1, 41)
    fx, fy = np.meshgrid(g, g)
    floor = np.stack([fx.ravel(), fy.ravel(), np.zeros(fx.size)], 1)
    parts = [_discs(floor, np.tile([0.0, 0, 1], (len(floor), 1)), 0.045)]
    wy, wz = np.meshgrid(np.linspace(-0.8, 0.8, 41), np.linspace(0.0, 1.0, 26))
    wall = np.stack([np.zeros(wy.size), wy.ravel(), wz.ravel()], 1)
    parts.append(_discs(wall, np.tile([1.0, 0, 0], (len(wall), 1)), 0.035))
    rng = np.random.default_rng(0)
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    parts.append(_discs(TARGET + TARGET_RADIUS * d, d, 0.02))
    means = np.concatenate([p[0] for p in parts])
    rot = np.concatenate([p[1] for p in parts])
    radii = np.concatenate([p[2] for p in parts])
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    return EllipsoidScene(t(means), t(rot), t(radii), torch.ones(len(means), dtype=torch.float64), camera_radius)
