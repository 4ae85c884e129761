"""SemanticScene.query / locate with a known codec and text encoder; label-table text encoder."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from cinenerf_ns.method.relevancy import QueryError, relevancy_from_features
from cinenerf_ns.method.semantic_scene import SemanticScene, build_text_encoder


class IdentityCodec:
    """Latents are 3-dim unit 'features' directly (D = 3)."""

    def decode(self, l):
        return F.normalize(l, dim=-1)


WORDS = {
    "red chair": [1.0, 0.0, 0.0],
    "palm tree": [0.0, 1.0, 0.0],
    "object": [0.3, 0.3, 0.9],
    "things": [0.2, 0.3, 0.9],
    "stuff": [0.3, 0.2, 0.9],
    "texture": [0.25, 0.25, 0.95],
}


def enc(texts):
    return F.normalize(torch.tensor([WORDS[t] for t in texts]), dim=-1)


def _scene(**kw):
    # 4 "chair" Gaussians around (1, 2, 0), 3 "tree" Gaussians around (-5, 0, 0), 1 faint chair one far away
    means = torch.tensor([[1.0, 2, 0], [1.2, 2, 0], [0.8, 2, 0], [1.0, 2.4, 0], [-5, 0, 0], [-5, 1, 0], [-5, 0, 1],
                          [50, 50, 50]])
    lat = torch.tensor([[1.0, 0, 0]] * 4 + [[0, 1.0, 0]] * 3 + [[1.0, 0, 0]])
    opac = torch.tensor([1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.01])
    return SemanticScene(means, opac, lat, IdentityCodec(), enc, **kw)


def test_query_equals_formula():
    s = _scene()
    rel = s.query("red chair")
    d = F.normalize(s.latents, dim=-1)
    ref = relevancy_from_features(d, enc(["red chair"])[0], enc(["object", "things", "stuff", "texture"]), 10.0)
    assert torch.allclose(rel, ref)
    assert (rel[:4] > 0.5).all() and (rel[4:7] < 0.5).all()


def test_locate_centroid_and_mask():
    s = _scene(min_opacity=0.05, centre="surface")
    c, mask = s.locate("red chair")
    assert mask.tolist() == [True] * 4 + [False] * 4  # the faint far Gaussian is dropped by min_opacity
    assert torch.allclose(c, torch.tensor([1.0, 2.1, 0.0]))
    full = s.locate_full("palm tree")
    assert full.mask.sum() == 3 and torch.allclose(full.lo, torch.tensor([-5.0, 0, 0]))
    assert torch.allclose(full.hi, torch.tensor([-5.0, 1, 1]))
    # without the opacity floor the faint Gaussian joins but barely moves the opacity-weighted centroid
    c2, m2 = _scene(centre="surface").locate("red chair")
    assert m2.sum() == 5 and (c2 - c).norm() < 0.6


def test_errors():
    s = _scene()
    for bad in ["", "   "]:
        with pytest.raises(QueryError, match="empty"):
            s.query(bad)
    with pytest.raises(QueryError, match="nothing in the scene matches"):
        s.locate("red chair", threshold=0.9999)
    with pytest.raises(ValueError, match="inconsistent"):
        SemanticScene(torch.zeros(3, 3), torch.zeros(2), torch.zeros(3, 3), IdentityCodec(), enc)


def test_label_table_encoder_needs_no_clip_for_label_names():
    info = {"label_names": ["Floor", "palm tree"], "clip": None}
    emb = F.normalize(torch.randn(2, 8), dim=-1)
    e = build_text_encoder(info, emb)
    out = e(["palm tree", " floor "])
    assert torch.allclose(out, emb[[1, 0]])
    with pytest.raises(QueryError, match="only its label names"):
        e(["sofa"])


@pytest.mark.parametrize("n_names,n_emb", [(2, 1), (2, 3), (2, 0), (0, 2)])
def test_label_names_and_embeddings_that_disagree_are_refused(n_names, n_emb):
    """Issue 38: such a scene answered its labels through the (random) CLIP tower without a word."""
    from cinenerf_ns.method.scene_files import CheckpointError

    info = {"label_names": [f"thing {i}" for i in range(n_names)], "clip": {"random_weights": True}}
    emb = F.normalize(torch.randn(n_emb, 8), dim=-1) if n_emb else None
    with pytest.raises(CheckpointError, match=rf"{n_names} label names .* but {n_emb} label embeddings"):
        build_text_encoder(info, emb)


def test_label_table_then_clip_text_tower(tiny_clip_models):
    from cinenerf_ns.method.clip_features import ClipFeatureConfig, make_text_encoder

    cfg = ClipFeatureConfig(model_name=tiny_clip_models[0], random_weights=True, random_seed=2)
    emb = F.normalize(torch.randn(1, 32), dim=-1)
    e = build_text_encoder({"label_names": ["lamp"], "clip": cfg.spec()}, emb)
    ref = make_text_encoder(cfg)(["a sofa"])
    out = e(["lamp", "a sofa"])
    assert torch.allclose(out[0], emb[0]) and torch.allclose(out[1], ref[0], atol=1e-6)


def test_label_query_is_contrasted_against_the_other_labels():
    """A label-trained scene: 'b' must beat the other labels, not just the generic negatives."""
    import torch.nn.functional as F

    from cinenerf_ns.method.semantic_scene import SemanticScene

    torch.manual_seed(0)
    D = 8
    emb = F.normalize(torch.randn(4, D), dim=-1)
    names = ["a", "b", "c", "object"]
    table = dict(zip(names, emb))

    def enc(texts):
        return torch.stack([table[t.strip().lower()] for t in texts])

    class IdentityCodec(torch.nn.Module):  # latents ARE the features here (D-dim "latents")
        def decode(self, z):
            return F.normalize(z, dim=-1)

    # Gaussians 0-9 carry 'a', 10-19 carry 'b'; generic negative 'object' is far from both
    lat = torch.cat([emb[0].expand(10, D), emb[1].expand(10, D)])
    means = torch.randn(20, 3)
    plain = SemanticScene(means, torch.ones(20), lat, IdentityCodec(), enc, negatives=["object"])
    labelled = SemanticScene(means, torch.ones(20), lat, IdentityCodec(), enc, negatives=["object"],
                             label_names=["a", "b", "c"])
    r_plain, r_lab = plain.query("b"), labelled.query("b")
    # with the other labels as negatives, the 'a' Gaussians fall below 0.5 and the 'b' ones stay above
    assert (r_lab[:10] < 0.5).all() and (r_lab[10:] > 0.5).all()
    assert torch.allclose(r_plain, plain.query("b"))
    _, mask = labelled.locate("b")
    assert mask[10:].all() and not mask[:10].any()
    # free text (not a label) keeps the generic negatives
    assert labelled._embed("object")[1].shape[0] == 1


def test_smooth_latents_matches_brute_force():
    from cinenerf_ns.method.semantic_scene import smooth_latents

    g = torch.Generator().manual_seed(0)
    means = torch.rand(200, 3, generator=g, dtype=torch.float64)
    op = torch.rand(200, generator=g, dtype=torch.float64)
    lat = torch.randn(200, 3, generator=g, dtype=torch.float64)
    out = smooth_latents(means, op, lat, 5)
    d = torch.cdist(means, means)
    idx = d.argsort(1)[:, :5]  # brute-force 5 nearest (itself first)
    w = op[idx]
    ref = (lat[idx] * w[..., None]).sum(1) / w.sum(1, keepdim=True)
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-6)
    assert smooth_latents(means, op, lat, 1) is lat


def test_knn_indices_in_leaf_order_are_the_plain_querys():
    """Asking the tree in its leaf order changes the order of the work, not one answer (clustered points, k = 32)."""
    from scipy.spatial import cKDTree

    from cinenerf_ns.method.semantic_scene import knn_indices

    rng = np.random.default_rng(0)
    centres = rng.uniform(-3, 3, (40, 3))
    pts = (centres[rng.integers(0, 40, 6000)] + rng.normal(0, 0.05, (6000, 3))).astype(np.float32)
    pts = pts[rng.permutation(len(pts))]  # no spatial order, as a trained splat
    _, ref = cKDTree(pts).query(pts, k=32)
    got = knn_indices(pts, 32)
    assert got.dtype == ref.dtype and np.array_equal(got, ref)
    assert np.array_equal(got[:, 0], np.arange(len(pts)))  # itself first (distinct points)


def test_dominant_cluster_keeps_the_heaviest_connected_group():
    from cinenerf_ns.method.semantic_scene import dominant_cluster

    g = torch.Generator().manual_seed(0)
    a = torch.randn(50, 3, generator=g) * 0.01 + torch.tensor([0.0, 0.0, 0.0])  # dense blob, light weights
    b = torch.randn(20, 3, generator=g) * 0.01 + torch.tensor([1.0, 0.0, 0.0])  # far blob, heavy weights
    c = torch.tensor([[0.5, 0.5, 0.5]])  # an isolated false positive
    means = torch.cat([a, b, c])
    w = torch.cat([torch.full((50,), 0.1), torch.full((20,), 1.0), torch.tensor([5.0])])
    mask = torch.ones(71, dtype=torch.bool)
    out = dominant_cluster(means, mask, w, voxel=0.05)
    # heaviest group: the isolated point weighs 5.0 < 20 x 1.0 of blob b > 50 x 0.1 of blob a
    assert out[50:70].all() and not out[:50].any() and not out[70]
    # only ever a subset of the mask; unselected Gaussians never join
    mask2 = mask.clone()
    mask2[55] = False
    out2 = dominant_cluster(means, mask2, w, voxel=0.05)
    assert not out2[55] and out2[50:55].all()
    # a single selected Gaussian is returned as is
    one = torch.zeros(71, dtype=torch.bool)
    one[3] = True
    assert torch.equal(dominant_cluster(means, one, w, voxel=0.05), one)


def test_locate_with_clusters_picks_one_instance():
    import torch.nn.functional as F

    from cinenerf_ns.method.semantic_scene import SemanticScene

    emb = F.normalize(torch.eye(4)[:2], dim=-1)  # 'chair', 'object'
    table = {"chair": emb[0], "object": emb[1]}
    enc = lambda texts: torch.stack([table[t] for t in texts])  # noqa: E731

    class IdentityCodec(torch.nn.Module):
        def decode(self, z):
            return F.normalize(z, dim=-1)

    g = torch.Generator().manual_seed(1)
    # two chairs 1 unit apart (30 and 10 Gaussians) and floor Gaussians that are 'object'
    chairs = torch.cat([torch.randn(30, 3, generator=g) * 0.02,
                        torch.randn(10, 3, generator=g) * 0.02 + torch.tensor([1.0, 0, 0])])
    floor = torch.rand(60, 3, generator=g) * 2 - 1
    means = torch.cat([chairs, floor])
    lat = torch.cat([emb[0].expand(40, 4), emb[1].expand(60, 4)])
    plain = SemanticScene(means, torch.ones(100), lat, IdentityCodec(), enc, negatives=["object"])
    clus = SemanticScene(means, torch.ones(100), lat, IdentityCodec(), enc, negatives=["object"], cluster_fraction=0.02)
    c0, m0 = plain.locate("chair")
    c1, m1 = clus.locate("chair")
    assert int(m0.sum()) == 40 and 0.15 < float(c0[0]) < 0.85  # a centre of both chairs: empty space between them
    assert int(m1.sum()) == 30 and float(c1.norm()) < 0.05  # one chair (the heavier one)


def test_locate_volume_centre_is_the_default_and_keeps_the_surface_centroid():
    """Default centre="volume": object_centre.volume_centroid of the selection (here 4 points in a plane: a few
    voxels), and LocateResult.surface_centroid is the opacity-weighted mean."""
    from cinenerf_ns.method.object_centre import volume_centroid

    s = _scene(min_opacity=0.05)
    r = s.locate_full("red chair")
    assert torch.allclose(r.surface_centroid, torch.tensor([1.0, 2.1, 0.0]))
    ref = volume_centroid(s.means[r.mask])
    assert torch.allclose(r.centroid.double(), torch.as_tensor(ref), atol=1e-6)


def test_volume_centre_uses_gaussian_extents_and_validates():
    means = torch.tensor([[1.0, 2, 0], [1.2, 2, 0], [0.8, 2, 0], [1.0, 2.4, 0], [-5, 0, 0], [-5, 1, 0], [-5, 0, 1],
                          [50, 50, 50]])
    lat = torch.tensor([[1.0, 0, 0]] * 4 + [[0, 1.0, 0]] * 3 + [[1.0, 0, 0]])
    opac = torch.tensor([1.0] * 7 + [0.01])
    quats = torch.tensor([[1.0, 0, 0, 0]] * 8)
    big = torch.full((8, 3), math.log(0.3))
    s = SemanticScene(means, opac, lat, IdentityCodec(), enc, min_opacity=0.05, log_scales=big, quats=quats)
    r = s.locate_full("red chair")
    from cinenerf_ns.method.object_centre import volume_centroid

    ref = volume_centroid(means[r.mask], torch.exp(big[r.mask]), quats[r.mask])
    assert torch.allclose(r.centroid.double(), torch.as_tensor(ref), atol=1e-6)
    with pytest.raises(ValueError, match="centre"):
        SemanticScene(means, opac, lat, IdentityCodec(), enc, centre="middle")
    with pytest.raises(ValueError, match="log_scales"):
        SemanticScene(means, opac, lat, IdentityCodec(), enc, log_scales=big[:3])


def test_locate_drops_the_floor_under_the_object():
    """A 'chair' column standing on a floor whose Gaussians around its foot also carry 'chair' (feature bleed):
    locate drops that floor layer (object_support.drop_support_layer with a ring of 1/2-3/2 clustering voxels);
    drop_support=False keeps it."""
    from cinenerf_ns.method.object_support import drop_support_layer

    g = torch.Generator().manual_seed(0)
    col = torch.rand(3000, 3, generator=g) * torch.tensor([0.2, 0.2, 1.0]) + torch.tensor([-0.1, -0.1, 0.0])
    floor = torch.cat([torch.rand(6000, 2, generator=g) * 4 - 2, torch.randn(6000, 1, generator=g) * 0.003], 1)
    means = torch.cat([col, floor])
    near = floor[:, :2].abs().max(1).values < 0.2  # the floor right around the column's foot
    lat = torch.cat([torch.tensor([[1.0, 0, 0]]).expand(3000, 3),
                     torch.where(near[:, None], torch.tensor([1.0, 0, 0]), torch.tensor([0.3, 0.3, 0.9]))])
    kw = dict(cluster_fraction=0.02)
    on = SemanticScene(means, torch.ones(len(means)), lat, IdentityCodec(), enc, **kw)
    off = SemanticScene(means, torch.ones(len(means)), lat, IdentityCodec(), enc, drop_support=False, **kw)
    m_off = off.locate_full("red chair").mask
    m_on = on.locate_full("red chair").mask
    assert m_off[3000:].sum() == near.sum()  # the bled floor is selected
    assert m_on[3000:].sum() <= 0.1 * near.sum() and m_on[:3000].float().mean() > 0.97
    v = on._voxel()
    assert torch.equal(m_on, drop_support_layer(means, m_off, inner=0.5 * v, outer=1.5 * v))


WEAK_CHAIR = [1.0 + 0.95 * 0.3, 0.95 * 0.3, 0.95 * 0.9]  # between "red chair" and the negatives: relevancy ~0.55


def _cored_scene(n_core=300, n_weak=60, **kw):
    """A 'chair' blob at the origin (strong latents) with weakly labelled Gaussians 0.5 to its +x side (e.g. a wall
    the chair shows through), and a 'tree' blob far away."""
    g = torch.Generator().manual_seed(0)
    core = torch.randn(n_core, 3, generator=g) * 0.05
    weak = torch.randn(n_weak, 3, generator=g) * 0.05 + torch.tensor([0.5, 0.0, 0.0])
    tree = torch.randn(100, 3, generator=g) * 0.05 + torch.tensor([-3.0, 0.0, 0.0])
    means = torch.cat([core, weak, tree])
    lat = torch.cat([torch.tensor([[1.0, 0, 0]]).expand(n_core, 3), torch.tensor([WEAK_CHAIR]).expand(n_weak, 3),
                     torch.tensor([[0.0, 1.0, 0]]).expand(100, 3)])
    opac = torch.rand(len(means), generator=g) * 0.5 + 0.5
    return SemanticScene(means, opac, lat, IdentityCodec(), enc, drop_support=False, **kw)


@pytest.mark.parametrize("centre", ["surface", "volume"])
def test_centre_comes_from_the_confident_core_and_the_selection_is_unchanged(centre):
    """centre_relevancy (default 0.65): the centre is estimated from the selected Gaussians above it; the mask and
    the extent are those of the whole selection (threshold 0.5); 0 restores the whole-selection centre."""
    from cinenerf_ns.method.object_centre import volume_centroid
    from cinenerf_ns.method.relevancy import object_centroid_extent

    on = _cored_scene(centre=centre)
    off = _cored_scene(centre=centre, centre_relevancy=0.0)
    assert on.centre_relevancy == 0.65
    r, r0 = on.locate_full("red chair"), off.locate_full("red chair")
    weak = r.relevancy[300:360]
    assert ((weak > 0.5) & (weak < 0.65)).all()  # the premise: the side Gaussians are selected, weakly
    assert torch.equal(r.mask, r0.mask) and r.mask[:360].all() and not r.mask[360:].any()
    assert torch.equal(r.lo, r0.lo) and torch.equal(r.hi, r0.hi) and float(r.hi[0]) > 0.4  # extent reaches the side
    assert r.core[:300].all() and not r.core[300:].any() and torch.equal(r0.core, r0.mask)
    if centre == "surface":
        ref, _, _ = object_centroid_extent(on.means, on.opacities, r.core)
        ref0, _, _ = object_centroid_extent(on.means, on.opacities, r.mask)
    else:
        ref = torch.as_tensor(volume_centroid(on.means[r.core]), dtype=torch.float32)
        ref0 = torch.as_tensor(volume_centroid(on.means[r.mask]), dtype=torch.float32)
    assert torch.allclose(r.centroid, ref, atol=1e-6) and torch.allclose(r0.centroid, ref0, atol=1e-6)
    assert float(r.centroid.norm()) < 0.03 < float(r0.centroid[0])  # the side Gaussians pulled the old centre to +x
    assert torch.allclose(r.surface_centroid, object_centroid_extent(on.means, on.opacities, r.core)[0])


def test_centre_core_falls_back_to_the_selection_when_it_is_small():
    """A core under a quarter of the selection is not trusted: the centre comes from the whole selection."""
    s = _cored_scene(n_core=50, n_weak=400, centre="surface")
    r = s.locate_full("red chair")
    assert int(r.mask.sum()) == 450 and torch.equal(r.core, r.mask)
    off = _cored_scene(n_core=50, n_weak=400, centre="surface", centre_relevancy=0.0)
    assert torch.equal(r.centroid, off.locate_full("red chair").centroid)


@pytest.mark.parametrize("bad", [1.0, -0.1, float("nan"), float("inf"), "high", None])
def test_centre_relevancy_is_validated(bad):
    with pytest.raises(ValueError, match="centre_relevancy"):
        _cored_scene(centre_relevancy=bad)


def test_camera_centres_reach_the_volume_centre_and_are_validated():
    """camera_centres: stored as float64 [C, 3] and passed to volume_centroid (the unseen fill); NaN is an error; an
    empty array is the same as none."""
    import numpy as np

    from cinenerf_ns.method.object_centre import volume_centroid

    rng = np.random.default_rng(0)
    g = np.stack(np.meshgrid(*[np.linspace(0, 1, 12)] * 3, indexing="ij"), -1).reshape(-1, 3)
    box = g[(g == 0).any(1) | (g == 1).any(1)]  # the surface of a unit cube: 12 x 12 points a face
    box = box[box[:, 1] < 1]  # its back (y = 1) never seen
    means = torch.as_tensor(np.concatenate([box, rng.uniform(-4, -3, (5, 3))]), dtype=torch.float32)
    lat = torch.tensor([[1.0, 0, 0]] * len(box) + [[0, 1.0, 0]] * 5)
    opac = torch.ones(len(means))
    cams = np.array([[0.5, -3.0, 0.6], [2.0, -2.0, 1.5], [-1.0, -2.5, 1.0]])
    s = SemanticScene(means, opac, lat, IdentityCodec(), enc, camera_centres=torch.as_tensor(cams))
    assert s.camera_centres.dtype == np.float64 and s.camera_centres.shape == (3, 3)
    r = s.locate_full("red chair")
    want = volume_centroid(means[r.core], cameras=cams)
    np.testing.assert_allclose(r.centroid.double().numpy(), want, atol=1e-6)
    plain = SemanticScene(means, opac, lat, IdentityCodec(), enc).locate_full("red chair").centroid
    assert not torch.allclose(plain, r.centroid)  # the cameras changed the estimate (they fill the unseen back)
    assert SemanticScene(means, opac, lat, IdentityCodec(), enc, camera_centres=np.zeros((0, 3))).camera_centres is None
    with pytest.raises(ValueError, match="camera_centres"):
        SemanticScene(means, opac, lat, IdentityCodec(), enc, camera_centres=[[0.0, float("nan"), 1.0]])


# --------------------------------------------------------------------------- locate cache and warm() (issue 23)
class Counting:
    """A text encoder / relevancy wrapper that counts its calls."""

    def __init__(self, fn):
        self.fn, self.calls = fn, 0

    def __call__(self, *a, **kw):
        self.calls += 1
        return self.fn(*a, **kw)


def test_repeated_query_is_answered_from_the_cache(monkeypatch):
    import cinenerf_ns.method.semantic_scene as ss

    rel = Counting(ss.relevancy_fn)
    monkeypatch.setattr(ss, "relevancy_fn", rel)
    e = Counting(enc)
    s = _scene()
    s.text_encoder = e
    a = s.locate_full("red chair")
    n_enc, n_rel = e.calls, rel.calls
    assert n_enc >= 1 and n_rel == 1
    b = s.locate_full("  Red   CHAIR ")  # the same normalised text
    assert b is a and e.calls == n_enc and rel.calls == n_rel
    c, m = s.locate("red chair")
    assert torch.equal(c, a.centroid) and torch.equal(m, a.mask) and rel.calls == n_rel
    fresh = _scene().locate_full("red chair")  # equal to an uncached answer (another scene: relevancy once more)
    assert torch.equal(fresh.mask, a.mask) and torch.allclose(fresh.centroid, a.centroid)
    n_rel = rel.calls
    # a different threshold is a different entry; the default threshold given explicitly is the same entry
    d = s.locate_full("red chair", threshold=0.6)
    assert d is not a and rel.calls == n_rel + 1
    assert s.locate_full("red chair", threshold=s.threshold) is a and rel.calls == n_rel + 1
    # a failed query is not cached: it raises every time
    for _ in range(2):
        with pytest.raises(QueryError, match="nothing in the scene matches"):
            s.locate_full("red chair", threshold=0.9999)
    assert rel.calls == n_rel + 3


def test_locate_cache_is_bounded_and_least_recently_used():
    s = _scene()
    s.cache_size = 2
    a = s.locate_full("red chair", threshold=0.5)
    b = s.locate_full("red chair", threshold=0.6)
    assert s.locate_full("red chair", threshold=0.5) is a  # a is now the most recent
    s.locate_full("palm tree")  # evicts b
    assert len(s._cache) == 2
    assert s.locate_full("red chair", threshold=0.5) is a
    assert s.locate_full("red chair", threshold=0.6) is not b


def test_settings_change_is_a_new_cache_entry():
    s = _scene(centre="surface")
    a = s.locate_full("red chair")
    s.centre = "volume"
    assert s.locate_full("red chair") is not a


def test_warm_smooths_once_and_answers_the_labels(monkeypatch):
    import cinenerf_ns.method.semantic_scene as ss

    smooth = Counting(ss.smooth_latents)
    monkeypatch.setattr(ss, "smooth_latents", smooth)
    rel = Counting(ss.relevancy_fn)
    monkeypatch.setattr(ss, "relevancy_fn", rel)
    s = _scene(smooth_neighbors=3, label_names=["red chair", "palm tree"])
    t = s.warm()
    assert smooth.calls == 1 and set(t) >= {"smooth_s", "extent_s", "labels_s"}
    n_rel = rel.calls
    assert n_rel == 2  # one per label
    r = s.locate_full("red chair")  # the first query: neither smoothing nor relevancy again
    assert smooth.calls == 1 and rel.calls == n_rel and r.mask.any()
    s.locate_full("red chair", threshold=0.7)  # another threshold: relevancy again, smoothing still not
    assert smooth.calls == 1 and rel.calls == n_rel + 1
    s2 = _scene(smooth_neighbors=3)  # without warm(): the first query smooths (lazily, once)
    s2.locate_full("red chair")
    s2.locate_full("palm tree")
    assert smooth.calls == 2


def test_decoded_norms_are_computed_once_and_change_no_relevancy(monkeypatch):
    """With a real codec the text-independent half of a relevancy (the decoded norms) is computed once per scene, in
    relevancy's chunks, and every query's relevancy stays the one relevancy() computes alone, bit for bit."""
    import cinenerf_ns.method.semantic_scene as ss
    from cinenerf_ns.method.codec import FeatureCodec
    from cinenerf_ns.method.relevancy import relevancy

    g = torch.Generator().manual_seed(0)
    codec = FeatureCodec(16).eval()
    table = {t: torch.randn(16, generator=g) for t in ("red chair", "palm tree", "object", "things", "stuff",
                                                      "texture")}
    enc16 = lambda texts: F.normalize(torch.stack([table[t] for t in texts]), dim=-1)  # noqa: E731
    n = 1000
    lat = torch.tanh(torch.randn(n, 3, generator=g))
    monkeypatch.setattr(ss, "RELEVANCY_CHUNK", 300)  # chunks of 300, 300, 300 and 100
    norms = Counting(codec.decoded_sq_norms)
    monkeypatch.setattr(codec, "decoded_sq_norms", norms)
    s = SemanticScene(torch.randn(n, 3, generator=g), torch.rand(n, generator=g), lat, codec, enc16)
    assert s.warm(labels=False)["norms_s"] >= 0 and norms.calls == 4
    for text in ("red chair", "palm tree", "red chair"):
        q, neg = s._embed(text)
        assert torch.equal(s.query(text), relevancy(lat, codec, q, neg, temperature=s.temperature, chunk=300))
    assert norms.calls == 4


def test_warm_in_a_thread_while_querying():
    import threading

    s = _scene(smooth_neighbors=3, label_names=["red chair", "palm tree"])
    th = threading.Thread(target=s.warm)
    th.start()
    r = s.locate_full("palm tree")
    th.join()
    assert s.locate_full("palm tree") is r and r.mask.sum() == 3


def test_warm_stops_between_labels_when_asked():
    """warm(stop=event): a viewer shutting down sets the event; the warm-up returns after the part in progress."""
    import threading

    s = _scene(smooth_neighbors=3, label_names=["red chair", "palm tree"])
    stop = threading.Event()
    stop.set()
    assert s.warm(stop=stop) == {"stopped": 1.0} and s._smoothed is None and not s._cache
    seen = []
    real = s._locate_uncached

    def first_label_then_stop(text, threshold=None):
        seen.append(text)
        stop.set()
        return real(text, threshold)

    stop.clear()
    s._locate_uncached = first_label_then_stop
    t = s.warm(stop=stop)
    assert seen == ["red chair"] and t["stopped"] == 1.0 and "labels_s" not in t and len(s._cache) == 1
