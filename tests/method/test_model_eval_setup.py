"""The stock nerfstudio loading path (eval_setup, used by ns-render / ns-viewer / ns-eval) restores a
cinesplat checkpoint under torch's weights_only default, on a tiny synthetic nerfstudio dataset (CPU)."""
from __future__ import annotations

import inspect

import torch
from _ns_stack import stack_without_sources


def test_eval_setup_loads_cinesplat_checkpoint(tmp_path, tiny_clip_models, tiny_scene, monkeypatch):
    import numpy as np
    from nerfstudio.engine.optimizers import Optimizers

    # eval_utils imports nerfstudio's method list, which reads inspect.stack() (tests/_ns_stack.py says why this one)
    monkeypatch.setattr(inspect, "stack", stack_without_sources)
    from nerfstudio.utils.eval_utils import eval_setup

    from cinenerf_ns.method.cinesplat_config import make_cinesplat_config

    data = tmp_path / "scene"
    tiny_scene(data)
    cfg = make_cinesplat_config()
    cfg.output_dir = tmp_path / "outputs"
    cfg.experiment_name = "tiny"
    cfg.timestamp = "run"
    cfg.pipeline.datamanager.data = data
    cfg.pipeline.datamanager.dataparser.data = data
    cfg.pipeline.datamanager.cache_images = "gpu"  # on a CPU device: stays on the CPU (no pinned memory)
    cfg.pipeline.datamanager.clip.model_name = tiny_clip_models[0]
    cfg.pipeline.datamanager.clip.random_weights = True
    cfg.pipeline.datamanager.clip.input_long_sides = (64,)
    cfg.pipeline.datamanager.clip.feature_long_side = 8
    cfg.pipeline.datamanager.codec.train_steps = 30
    cfg.pipeline.datamanager.codec.batch_size = 256
    cfg.pipeline.model.num_random = 300
    cfg.pipeline.model.lpips = "off"
    pipeline = cfg.pipeline.setup(device="cpu", test_mode="val", world_size=1, local_rank=0, grad_scaler=None)
    with torch.no_grad():
        pipeline.model.gauss_params["latents"].uniform_(-1, 1)
    opts = Optimizers(cfg.optimizers.copy(), pipeline.get_param_groups())
    for group in opts.parameters:
        for p in opts.parameters[group]:
            p.grad = torch.zeros_like(p)
    opts.optimizer_step_all()
    opts.scheduler_step_all(0)
    ckpt_dir = cfg.get_checkpoint_dir()
    ckpt_dir.mkdir(parents=True)
    cfg.save_config()
    torch.save(
        {
            "step": 7,
            "pipeline": pipeline.state_dict(),
            "optimizers": {k: v.state_dict() for k, v in opts.optimizers.items()},
            "schedulers": {k: v.state_dict() for k, v in opts.schedulers.items()},
            "scalers": {"legacy_numpy": np.float64(1.0)},  # a stock-nerfstudio-style numpy scalar as well
        },
        ckpt_dir / "step-000000007.ckpt",
    )
    # cinesplat's own schedules store python floats only
    for sd in (v.state_dict() for v in opts.schedulers.values()):
        assert all(type(x) is float for x in sd["_last_lr"])

    _, loaded, ckpt_path, step = eval_setup(cfg.get_base_dir() / "config.yml", test_mode="inference")
    assert step == 7
    m0, m1 = pipeline.model, loaded.model
    assert torch.equal(m1.gauss_params["latents"].cpu(), m0.gauss_params["latents"].detach().cpu())
    assert m1.cine_info["feature_long_side"] == 8 and m1.codec is not None
    x = torch.rand(5, 3)
    assert torch.allclose(m1.codec.decode(x.to(m1.device)).cpu(), m0.codec.decode(x).cpu())
    # and the trainer-free loader reads the same file
    from cinenerf_ns.method.checkpoint import load_splat

    st = load_splat(cfg.get_base_dir() / "config.yml")
    assert np.array_equal(st.params.latents, m0.gauss_params["latents"].detach().cpu().numpy())
