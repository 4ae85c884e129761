"""gsplat's DefaultStrategy duplicates / splits / prunes the latents in step with the other attributes.

Runs the strategy's own grow / prune code on CPU (pure torch in gsplat 1.5.3); the GPU test file runs the
same check through real training steps."""
from __future__ import annotations

import torch
from nerfstudio.data.scene_box import SceneBox
from nerfstudio.engine.optimizers import Optimizers

from cinenerf_ns.method.cinesplat_config import make_cinesplat_config
from cinenerf_ns.method.model import CineSplatModel, CineSplatModelConfig


def _model_and_opt(n=40, device="cpu"):
    cfg = CineSplatModelConfig(random_init=True, num_random=n, lpips="off")
    m = CineSplatModel(cfg, scene_box=SceneBox(aabb=torch.tensor([[-1.0, -1, -1], [1, 1, 1]])), num_train_data=2,
                       metadata={})
    m.to(device)
    opts = Optimizers(make_cinesplat_config().optimizers, m.get_param_groups())
    return m, opts


def check_aligned(m, opts, parent_quats, parent_latents):
    """Every attribute has the same count; each Gaussian's latent belongs to its parent (matched by quats,
    which duplicate and split copy unchanged); optimizers point at the live parameters with matching state."""
    n = m.gauss_params["means"].shape[0]
    for name, p in m.gauss_params.items():
        assert p.shape[0] == n, name
        opt = opts.optimizers[name]
        assert opt.param_groups[0]["params"][0] is p, name
        st = opt.state[p]
        if st:
            assert st["exp_avg"].shape == p.shape, name
    lat = m.gauss_params["latents"].detach()
    q = m.gauss_params["quats"].detach()
    parent = lat[:, 0].round().long()  # latent channel 0 holds the parent's index
    assert torch.equal(q, parent_quats[parent])
    assert torch.equal(lat, parent_latents[parent])


def test_grow_and_prune_keep_latents_aligned():
    m, opts = _model_and_opt()
    n = m.num_points
    with torch.no_grad():
        m.gauss_params["latents"][:, 0] = torch.arange(n, dtype=torch.float32)
        m.gauss_params["latents"][:, 1:] = torch.randn(n, 2)
        # half tiny (duplicated), half large (split)
        m.gauss_params["scales"][: n // 2] = -8.0
        m.gauss_params["scales"][n // 2 :] = 0.0
    # one optimizer step so every group has Adam state to be resized
    loss = sum((p**2).sum() for p in m.gauss_params.values())
    loss.backward()
    for o in opts.optimizers.values():
        o.step()
    parent_q = m.gauss_params["quats"].detach().clone()
    parent_l = m.gauss_params["latents"].detach().clone()
    strat, state = m.strategy, m.strategy.initialize_state(scene_scale=1.0)
    grad_high = torch.zeros(n, dtype=torch.bool)
    grad_high[::3] = True
    state["grad2d"] = grad_high.float()
    state["count"] = torch.ones(n)
    state["radii"] = torch.zeros(n)
    state["scene_scale"] = 1.0
    o = {k: opts.optimizers[k] for k in m.gauss_params.keys()}
    n_dup, n_split = strat._grow_gs(m.gauss_params, o, state, step=600)
    assert n_dup > 0 and n_split > 0
    assert m.num_points == n + n_dup + n_split
    check_aligned(m, opts, parent_q, parent_l)
    with torch.no_grad():
        m.gauss_params["opacities"][::4] = -10.0  # pruned
    n_prune = strat._prune_gs(m.gauss_params, o, state, step=600)
    assert n_prune > 0
    check_aligned(m, opts, parent_q, parent_l)
