import warnings

import numpy as np
import pytest
import torch

from cinenerf_ns.planner.errors import EmptySceneError, InvalidInputError
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene, quat_wxyz_to_rotmat
from cinenerf_ns.planner.scene.ply import write_splat_ply
from cinenerf_ns.planner.scene.scene_config import SceneConfig


def test_from_splat_axes_and_rotation():
    q = torch.tensor([[1.0, 0, 0, 0], [0.0, 0, 0, 2.0]])  # identity; 180 deg about z (unnormalised)
    ls = torch.log(torch.tensor([[0.1, 0.2, 0.3], [0.1, 0.1, 0.1]]))
    op = torch.tensor([10.0, 0.0])  # sigmoid ~1, 0.5
    sc = EllipsoidScene.from_splat(torch.zeros(2, 3), q, ls, op, SceneConfig(beta=2.0))
    torch.testing.assert_close(sc.radii[0], 2 * torch.sigmoid(torch.tensor(10.0)) * torch.tensor([0.1, 0.2, 0.3]))
    torch.testing.assert_close(sc.radii[1], torch.full((3,), 0.1))
    torch.testing.assert_close(sc.rotations[1], torch.diag(torch.tensor([-1.0, -1.0, 1.0])))
    R = quat_wxyz_to_rotmat(torch.randn(100, 4, dtype=torch.float64))
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(100, 3, 3))
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(100, dtype=torch.float64))


def test_covariance_and_aabb_exact():
    g = torch.Generator().manual_seed(0)
    sc = EllipsoidScene(means=torch.randn(20, 3, generator=g, dtype=torch.float64),
                        rotations=quat_wxyz_to_rotmat(torch.randn(20, 4, generator=g, dtype=torch.float64)),
                        radii=torch.rand(20, 3, generator=g, dtype=torch.float64) + 0.1,
                        opacities=torch.ones(20, dtype=torch.float64))
    lo, hi = sc.aabb()
    # support function along +/- world axes from dense surface samples
    u = torch.randn(20000, 3, generator=g, dtype=torch.float64)
    u = u / u.norm(dim=-1, keepdim=True)
    pts = sc.means[:, None] + ((sc.rotations[:, None] * (sc.radii[:, None, None, :] * u[None, :, None, :])).sum(-1))
    assert (pts.amax(1) <= hi + 1e-12).all() and (pts.amin(1) >= lo - 1e-12).all()
    assert (hi - pts.amax(1)).max() < 1e-2 and (pts.amin(1) - lo).max() < 1e-2
    cov = sc.covariances()
    torch.testing.assert_close(torch.linalg.eigvalsh(cov), torch.sort(sc.radii**2, -1).values)


def test_from_ply_matches_from_splat(tmp_path):
    rng = np.random.default_rng(0)
    m, q = rng.normal(size=(30, 3)), rng.normal(size=(30, 4))
    s, o = rng.normal(size=(30, 3)) - 3, rng.normal(size=30) + 1
    p = write_splat_ply(tmp_path / "s.ply", m, q, s, o)
    cfg = SceneConfig(camera_radius=0.05, opacity_floor=0.2)
    a = EllipsoidScene.from_ply(p, cfg)
    t = lambda x: torch.tensor(np.asarray(x, np.float32))
    b = EllipsoidScene.from_splat(t(m), t(q), t(s), t(o), cfg)
    assert len(a) == len(b) and a.camera_radius == 0.05
    for x, y in ((a.means, b.means), (a.radii, b.radii), (a.rotations, b.rotations), (a.source_index, b.source_index)):
        torch.testing.assert_close(x, y)


def test_from_ply_errors(tmp_path):
    with pytest.raises(InvalidInputError):
        EllipsoidScene.from_ply(tmp_path / "missing.ply")
    p = write_splat_ply(tmp_path / "faint.ply", np.zeros((3, 3)), np.tile([1.0, 0, 0, 0], (3, 1)),
                        np.zeros((3, 3)), np.full(3, -10.0))
    with pytest.raises(EmptySceneError):
        EllipsoidScene.from_ply(p)


def test_repair_warns_once_and_counts():
    means = torch.zeros(5, 3)
    means[0, 0] = float("nan")
    q = torch.tensor([[1.0, 0, 0, 0]] * 5)
    q[1] = 0
    ls = torch.zeros(5, 3)
    ls[2] = -30  # tiny -> clamped
    ls[3, 0] = 50  # huge
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        sc = EllipsoidScene.from_splat(means, q, ls, torch.full((5,), 5.0), SceneConfig(max_axis=10.0))
    assert len(w) == 1 and "dropped 2" in str(w[0].message) and "dropped 1 with huge" in str(w[0].message)
    assert sc.source_index.tolist() == [2, 4]
    assert float(sc.radii[0].min()) == pytest.approx(1e-4)


def test_subset_to_bounds():
    sc = EllipsoidScene.from_splat(torch.randn(10, 3), torch.randn(10, 4), torch.full((10, 3), -2.0), torch.ones(10))
    sub = sc.subset(torch.tensor([1, 3]))
    assert len(sub) == 2 and sub.camera_radius == sc.camera_radius
    lo, hi = sc.bounds()
    assert lo.shape == (3,) and (lo < hi).all()
    assert sc.to(dtype=torch.float64).means.dtype == torch.float64


def test_empty_scene_names_the_cause():
    """All Gaussians dropped: the message says why (infinite scales are not an opacity-floor problem)."""
    from cinenerf_ns.planner.errors import EmptySceneError

    means, q = torch.zeros(4, 3), torch.tensor([[1.0, 0, 0, 0]] * 4)
    with pytest.raises(EmptySceneError, match=r"of 4 Gaussians, 4 have infinite scales; the scene file") as e:
        EllipsoidScene.from_splat(means, q, torch.full((4, 3), float("inf")), torch.full((4,), 5.0))
    assert "--opacity-floor" not in str(e.value)
    with pytest.raises(EmptySceneError, match=r"4 are fainter than the opacity floor 0.05 .*; lower --opacity-floor"):
        EllipsoidScene.from_splat(means, q, torch.zeros(4, 3), torch.full((4,), -10.0))
    ls = torch.zeros(4, 3)
    ls[:2] = float("inf")
    with pytest.raises(EmptySceneError, match=r"2 have infinite scales; 2 are fainter"):
        EllipsoidScene.from_splat(means, q, ls, torch.tensor([5.0, 5.0, -10.0, -10.0]))
