"""CineSplat: splatfacto + a 3-dim latent code per Gaussian distilled from pixel-aligned CLIP features.

Paper Sec. III-A. Every Gaussian carries ``gauss_params["latents"]`` [N, 3] with its own optimizer group
(named "latents"), so gsplat's DefaultStrategy duplicates / splits / prunes it in step with the other
attributes, and ``load_state_dict`` resizes it like them.

Distillation (eq. 3): l_hat = sum_i l_i T_i alpha_i is composited with DETACHED geometry, so the latent
loss reaches only the latents (the geometry is frozen *for this loss*, it keeps training on RGB). By default
("shared") the latent channels reuse the RGB pass's projection and tile lists: one extra gsplat
``rasterize_to_pixels`` on the detached 2D means / conics / opacities, no second projection, tile sort or host
sync (see ``latent_render_mode``). Loss: mean squared error between l_hat and f_enc(P) at the feature-map
resolution (see ``latent_render_resolution``). Schedule: joint training from
``latent_start_step`` (default 0) with detached geometry; set ``latent_start_step`` late (e.g. 2/3 of the
run) to distil only after the geometry has settled, as in the paper.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, List, Literal, Optional, Tuple, Type, Union

import torch
import torch.nn.functional as F
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.models.splatfacto import SplatfactoModel, SplatfactoModelConfig, get_viewmat
from nerfstudio.utils.rich_utils import CONSOLE
from nerfstudio.viewer.viewer_elements import ViewerText
from torch import Tensor
from torch.nn import Parameter

from cinenerf_ns.console_text import lit
from cinenerf_ns.method.codec import CodecConfig, FeatureCodec
from cinenerf_ns.method.compat import UnavailableLPIPS, offline_safe_lpips
from cinenerf_ns.method.feature_grid import feature_map_size
from cinenerf_ns.method.relevancy import DEFAULT_NEGATIVES, relevancy as relevancy_fn


def rasterize_to_pixels(*args, **kwargs):
    """gsplat's ``rasterize_to_pixels`` (imported on first use; tests on the CPU replace this name)."""
    from gsplat.cuda._wrapper import rasterize_to_pixels as _r2p

    return _r2p(*args, **kwargs)

# keys the datamanager puts into train_dataset.metadata for the model
META_CODEC_STATE = "cinesplat_codec_state"
META_INFO = "cinesplat_info"


VIEWER_EXTENSIONS = "cinenerf_ns.viewer_extensions"  # entry-point group: name -> callable(model) -> ViewerControl


@dataclass
class CineSplatModelConfig(SplatfactoModelConfig):
    """Splatfacto with a distilled 3-dim CLIP latent per Gaussian (Cine-NeRF, paper Sec. III)."""

    _target: Type = field(default_factory=lambda: CineSplatModel)
    latent_start_step: int = 0
    """Step from which the latent loss (eq. 3) is on; 0: joint with RGB (detached geometry leaves RGB unaffected).
    The paper distils after the geometry converged (e.g. 2/3 of the run)."""
    latent_loss_weight: float = 1.0
    """Weight of the latent L2 loss. Only the latents receive its gradient and they have their own Adam
    optimizer, so in "shared" and "separate" modes this mostly scales the logged value."""
    latent_every: int = 2
    """Render the latent pass and add its loss every this many steps. The 3-dim latents need far fewer updates than
    the geometry, and a step without the pass is exactly splatfacto's step, so 2 keeps label selection and costs
    about half the pass; 1: every step (slower)."""
    latent_render_mode: Literal["shared", "separate", "fused"] = "shared"
    """"shared": the 3 latent channels are rasterized on the RGB pass's projection and tile lists (its detached 2D
    means / conics / opacities): exact eq. 3 gradients (latents only) without a second projection, tile sort or
    host sync; "separate": a whole second gsplat pass on detached geometry (same gradients, slower); "fused": 3 extra
    channels of the RGB pass (one rasterization, but the latent loss also reaches the geometry: use a small
    weight)."""
    latent_side_stream: bool = True
    """"shared" mode on CUDA: rasterize the latents on a second CUDA stream, so that their forward and backward
    kernels (autograd runs a backward on its forward's stream) overlap the RGB pass's instead of queueing behind
    them: gsplat's small-image passes leave most of the GPU idle. Same images and gradients."""
    latent_render_resolution: Literal["feature", "image"] = "image"
    """"image": render at the RGB pass's resolution, area-downsample to the feature map; "feature": render at the
    map's size with a separate pass (fewer pixels but slower on a GPU: a few crowded tiles). "shared" and "fused"
    render at the RGB resolution (a separate pass at the map's size when the RGB pass is smaller than the map)."""
    lpips: Literal["auto", "cached", "off"] = "auto"
    """LPIPS eval metric: "auto" uses torchmetrics' LPIPS when its AlexNet weights are cached or downloadable,
    else skips it with one warning; "cached" never touches the network; "off" never builds it."""
    relevancy_negatives: Tuple[str, ...] = DEFAULT_NEGATIVES
    """Canonical negative phrases of the relevancy softmax (paper eq. 4, as in LERF)."""
    relevancy_temperature: float = 10.0
    """Multiplier of the cosine similarities inside the relevancy softmax (LERF uses 10; 1 is eq. 4 literally)."""
    relevancy_threshold: float = 0.5
    """Gaussians with relevancy above this belong to the queried object (viewer mask, locate())."""
    viewer_default_query: str = ""
    """Initial text of the viewer's relevancy query box."""
    viewer_cine_panel: bool = True
    """Add the cinematography panel (plan / fly / export collision-free shots) to nerfstudio's viewer
    (``ns-train cinesplat`` and ``ns-viewer``); it appears only when a viewer runs."""
    viewer_planner_device: str = "cpu"
    """Device the panel plans on: the Gaussians are copied there at each Plan ('cpu' keeps planning off the
    training GPU; 'cuda' is faster for millions of Gaussians)."""


class CineSplatModel(SplatfactoModel):
    """Splatfacto + per-Gaussian latents, a frozen feature codec and text-query relevancy."""

    config: CineSplatModelConfig

    # ------------------------------------------------------------------ construction
    def populate_modules(self):
        with offline_safe_lpips(self.config.lpips):
            super().populate_modules()
        n = self.gauss_params["means"].shape[0]
        dev = self.gauss_params["means"].device
        self.gauss_params["latents"] = Parameter(torch.zeros(n, 3, device=dev))  # [N, 3]
        meta = (self.kwargs.get("metadata") or {}) if hasattr(self, "kwargs") else {}
        info = dict(meta.get(META_INFO, {}) or {})
        self.cine_info: Dict[str, Any] = info  # feature source, text-encoder spec, label table, feature res
        self.cine_info.setdefault("sh_degree", int(self.config.sh_degree))
        self.codec: Optional[FeatureCodec] = None
        if META_CODEC_STATE in meta and info:
            self._build_codec(info)
            self.codec.load_state_dict(meta[META_CODEC_STATE])  # type: ignore[union-attr]
        # label table (feature_source == "labels"): names + their text embeddings [L, D]
        self.register_buffer("label_embeddings", torch.zeros(0), persistent=True)
        if "label_embeddings" in meta:
            self.label_embeddings = meta["label_embeddings"].float().clone()
        self._train_camera_hw: Dict[int, Tuple[int, int]] = {}  # cam_idx -> (H, W), see _camera_hw
        self._latent_stream: Optional[torch.cuda.Stream] = None  # latent_side_stream's stream, made on first use
        self._query_text = ""
        self._query_relevancy: Optional[Tensor] = None  # [N] cached per query / per point count
        self._text_encoder = None
        self.viewer_query = ViewerText(
            "CineSplat query",
            self.config.viewer_default_query,
            cb_hook=self._on_viewer_query,
            hint="text query; pick 'relevancy' in the output dropdown",
        )
        if self.config.viewer_default_query:
            self._query_text = self.config.viewer_default_query
        if self.config.viewer_cine_panel:
            self._attach_viewer_extensions()

    def _attach_viewer_extensions(self) -> None:
        """Viewer panels are attached from outside the method: every entry point of the group VIEWER_EXTENSIONS
        (pyproject; the cinematography panel of cinenerf_ns.viewer) is called with this model and its result is set
        as the attribute of its name. nerfstudio's Viewer finds such ViewerControls on the model (parse_object)
        and sets them up once the viser server exists, after a checkpoint has been loaded."""
        from importlib.metadata import entry_points

        for ep in entry_points(group=VIEWER_EXTENSIONS):
            setattr(self, ep.name, ep.load()(self))

    def k_nearest_sklearn(self, x: torch.Tensor, k: int):
        """splatfacto's initial-scale kNN with scipy's cKDTree in place of scikit-learn's NearestNeighbors: the same
        exact k nearest neighbours (computed in float64), so cinenerf_ns itself imports scipy only (scikit-learn is a
        dependency for plain splatfacto, which runs in the same environment).
        Returns (distances [N, k], indices [N, k]) float32 numpy arrays, the point itself excluded."""
        import numpy as np
        from scipy.spatial import cKDTree

        pts = x.detach().cpu().double().numpy()
        dist, idx = cKDTree(pts).query(pts, k=k + 1)
        return dist[:, 1:].astype(np.float32), idx[:, 1:].astype(np.float32)

    def _build_codec(self, info: Dict[str, Any]) -> None:
        cfg = CodecConfig(**info["codec_config"])
        # rebuild exactly the backend that was trained: torch weights load anywhere, tcnn ones need CUDA
        # (FeatureCodec raises a clear error when tinycudann is missing)
        cfg.backend = info.get("codec_backend", "torch")
        self.codec = FeatureCodec(int(info["feature_dim"]), cfg, device="cuda" if cfg.backend == "tcnn" else "cpu")
        for p in self.codec.parameters():
            p.requires_grad_(False)

    @property
    def latents(self) -> Tensor:
        return self.gauss_params["latents"]

    # the (text-encoder spec, codec config, label names) travel in the checkpoint as plain python data
    def get_extra_state(self) -> Any:
        return {"cine_info": self.cine_info}

    def set_extra_state(self, state: Any) -> None:
        if isinstance(state, dict) and "cine_info" in state:
            self.cine_info = dict(state["cine_info"])

    def load_state_dict(self, state_dict, **kwargs):  # type: ignore
        # build what the checkpoint holds before nn.Module copies tensors into it
        state_dict = dict(state_dict)
        extra = state_dict.get("_extra_state")
        if isinstance(extra, dict) and "cine_info" in extra:
            self.cine_info = dict(extra["cine_info"])
            if any(k.startswith("codec.") for k in state_dict):
                self._build_codec(self.cine_info)
                self.codec.to(self.device)  # type: ignore[union-attr]
        if "label_embeddings" in state_dict:
            self.label_embeddings = torch.zeros_like(state_dict["label_embeddings"], device=self.device)
        if "means" in state_dict and "gauss_params.means" not in state_dict:  # very old splatfacto layout
            state_dict["gauss_params.means"] = state_dict["means"]
        newp = state_dict["gauss_params.means"].shape[0] if "gauss_params.means" in state_dict else None
        if "gauss_params.latents" not in state_dict and newp is not None:
            # a plain splatfacto checkpoint: no latents yet (zeros), so it still loads
            state_dict["gauss_params.latents"] = torch.zeros(newp, 3)
            state_dict.setdefault("label_embeddings", torch.zeros(0))
        if "_extra_state" not in state_dict:
            state_dict["_extra_state"] = {"cine_info": self.cine_info}
        self._query_relevancy = None
        return super().load_state_dict(state_dict, **kwargs)

    def get_gaussian_param_groups(self) -> Dict[str, List[Parameter]]:
        gps = super().get_gaussian_param_groups()
        gps["latents"] = [self.gauss_params["latents"]]
        return gps

    # ------------------------------------------------------------------ metrics (offline LPIPS)
    def get_image_metrics_and_images(self, outputs, batch):
        metrics, images = super().get_image_metrics_and_images(outputs, batch)
        if isinstance(self.lpips, UnavailableLPIPS):
            metrics.pop("lpips", None)
            metrics.pop("cc_lpips", None)
        return metrics, images

    # ------------------------------------------------------------------ rendering
    def _camera_setup(self, camera: Cameras) -> Tuple[Tensor, Tensor, int, int]:
        """(viewmat [1,4,4], K [1,3,3], W, H) at full camera resolution, camera optimizer applied."""
        if self.training:
            c2w = self.camera_optimizer.apply_to_camera(camera)
        else:
            c2w = camera.camera_to_worlds
        viewmat = get_viewmat(c2w)
        K = camera.get_intrinsics_matrices().to(self.device)
        H, W = self._camera_hw(camera)
        return viewmat, K, W, H

    def _crop_ids(self) -> Optional[Tensor]:
        if self.crop_box is not None and not self.training:
            return self.crop_box.within(self.means).squeeze()
        return None

    def render_latents(
        self,
        viewmat: Tensor,
        K: Tensor,
        width: int,
        height: int,
        extra: Optional[Tensor] = None,
        crop_ids: Optional[Tensor] = None,
    ) -> Tuple[Tensor, Tensor]:
        """Eq. 3 with detached geometry: returns (latent image [H, W, 3(+E)], alpha [H, W, 1]).

        extra [N, E]: additional per-Gaussian channels composited in the same pass (e.g. relevancy).
        """
        sel = slice(None) if crop_ids is None else crop_ids
        colors = self.latents[sel]  # [N, 3]
        if extra is not None:
            colors = torch.cat([colors, extra[sel].to(colors)], dim=-1)  # [N, 3+E]
        # detached geometry and camera: camera-pose refinement, if on, learns from RGB only
        render, alpha, _ = self._rasterize(colors, viewmat, K, width, height, sel=sel, detach=True)
        return render[0], alpha[0]

    def _rasterize(self, colors: Tensor, viewmat: Tensor, K: Tensor, width: int, height: int, sel=None,
                   detach: bool = False, absgrad: bool = False):
        """gsplat's rasterization of per-Gaussian ``colors`` [N', C] (no SH evaluation) over the Gaussians ``sel``
        (all when None), with splatfacto's settings; geometry and camera detached when ``detach``."""
        from gsplat.rendering import rasterization

        pick = (lambda t: t) if sel is None else (lambda t: t[sel])  # noqa: E731
        geo = (lambda t: t.detach()) if detach else (lambda t: t)  # noqa: E731
        return rasterization(
            means=geo(pick(self.means)),
            quats=geo(pick(self.quats)),
            scales=geo(torch.exp(pick(self.scales))),
            opacities=geo(torch.sigmoid(pick(self.opacities)).squeeze(-1)),
            colors=colors,
            viewmats=geo(viewmat),
            Ks=K,
            width=width,
            height=height,
            packed=False,
            near_plane=0.01,
            far_plane=1e10,
            render_mode="RGB",
            sh_degree=None,
            sparse_grad=False,
            absgrad=absgrad,
            rasterize_mode=self.config.rasterize_mode,
        )

    def _camera_hw(self, camera: Cameras) -> Tuple[int, int]:
        """(H, W) of a camera as python ints. Training cameras live on the GPU, where ``.item()`` waits for the
        GPU to finish all queued work: training sizes are read once per camera (``metadata["cam_idx"]``) and
        cached, so the step launches its work without a host synchronisation."""
        idx = camera.metadata.get("cam_idx") if (self.training and camera.metadata) else None
        if idx is None:
            return int(camera.height.item()), int(camera.width.item())
        hw = self._train_camera_hw.get(int(idx))
        if hw is None:
            hw = self._train_camera_hw[int(idx)] = (int(camera.height.item()), int(camera.width.item()))
        return hw

    def _latent_target_size(self, camera: Cameras) -> Tuple[int, int]:
        long_side = int(self.cine_info.get("feature_long_side", 64))
        return feature_map_size(*self._camera_hw(camera), long_side)

    def _latents_active(self) -> bool:
        return (
            self.training
            and self.codec is not None
            and self.step >= self.config.latent_start_step
            and (self.step - self.config.latent_start_step) % max(1, self.config.latent_every) == 0
        )

    def get_outputs(self, camera: Cameras) -> Dict[str, Union[torch.Tensor, List]]:
        if not isinstance(camera, Cameras):
            return {}
        if self.training and not self._latents_active():
            # a step without the latent pass is splatfacto's step: no camera set-up of our own (its intrinsics and
            # pose refinement cost host syncs; they had made latent_every=2 slower than every step)
            return super().get_outputs(camera)
        if self.training and self.config.latent_render_mode == "fused":
            return self._get_outputs_fused(camera)
        if self.training and self.config.latent_render_mode == "shared":
            h, w = self._latent_target_size(camera)
            H, W = self._camera_hw(camera)
            d = self._get_downscale_factor()
            if h <= int(H * (1 / d)) and w <= int(W * (1 / d)):  # splatfacto's pass covers the feature map
                outputs = super().get_outputs(camera)
                outputs["latent"] = self._shared_latents()
                return outputs
            # else: the separate pass at the feature map's size below (early coarse steps of a large feature map)
        # camera set-up BEFORE splatfacto's pass: it rescales the camera in place for its downscale factor
        # and the int width/height do not always round-trip (e.g. 270 -> 67 -> 268)
        viewmat, K, W, H = self._camera_setup(camera)
        target_hw = self._latent_target_size(camera)
        outputs = super().get_outputs(camera)
        if self.training:  # the latent pass is on (off steps returned above)
            Hd, Wd = self.last_size  # splatfacto's pass (1/2^k of the image early in training)
            # "image" never renders below the feature map: pooling would then upsample
            if self.config.latent_render_resolution == "feature" or target_hw[0] > Hd or target_hw[1] > Wd:
                h, w = target_hw
                Ks = K.clone()
                Ks[:, 0, :] *= w / W
                Ks[:, 1, :] *= h / H
                lat, _ = self.render_latents(viewmat, Ks, w, h)
            else:
                d = self._get_downscale_factor()
                Ks = K.clone()
                Ks[:, :2, :] /= d  # splatfacto's convention: pixel scale exactly 1/d, size floor(W/d)
                lat, _ = self.render_latents(viewmat, Ks, Wd, Hd)
            outputs["latent"] = lat  # [h, w, 3] (or [H/d, W/d, 3], area-pooled to [h, w] in the loss)
            return outputs
        # eval / viewer: latent (visualised) and relevancy images
        crop_ids = self._crop_ids()
        if crop_ids is not None and crop_ids.sum() == 0:
            outputs["latent"] = torch.zeros(H, W, 3, device=self.device)
            outputs["relevancy"] = torch.zeros(H, W, 1, device=self.device)
            return outputs
        rel = self.query_relevancy()  # [N] or None
        extra = rel[:, None] if rel is not None else None
        img, alpha = self.render_latents(viewmat, K, W, H, extra=extra, crop_ids=crop_ids)
        outputs["latent"] = (img[..., :3] * 0.5 + 0.5).clamp(0, 1)  # codes in [-1,1] -> RGB
        if rel is not None:
            outputs["relevancy"] = (img[..., 3:4] / alpha.clamp_min(1e-6)).clamp(0, 1) * (alpha > 1e-3)
        else:
            outputs["relevancy"] = torch.zeros(H, W, 1, device=self.device)
        return outputs

    def _shared_latents(self) -> Tensor:
        """Eq. 3 on the RGB pass just run (``self.info``): the latents composited with its projected Gaussians and
        tile lists, all DETACHED, so only the latents get this loss's gradient. Same image as ``render_latents`` on
        that camera (same projection, same sort), without re-projecting or re-sorting. Returns [Hd, Wd, 3]."""
        info = self.info
        args = (
            info["means2d"].detach(),
            info["conics"].detach(),
            self.latents[None],  # [1, N, 3]: one camera, not packed
            info["opacities"].detach(),  # [1, N], with splatfacto's antialiasing compensation when on
            info["width"],
            info["height"],
            info["tile_size"],
            info["isect_offsets"],
            info["flatten_ids"],
        )
        if not (self.config.latent_side_stream and self.latents.is_cuda):
            render, _ = rasterize_to_pixels(*args, packed=False)
            return render[0]
        main = torch.cuda.current_stream(self.latents.device)
        side = self._latent_stream
        if side is None:
            side = self._latent_stream = torch.cuda.Stream(device=self.latents.device)
        side.wait_stream(main)  # the projection and tile lists were written on the main stream
        with torch.cuda.stream(side):
            render, _ = rasterize_to_pixels(*args, packed=False)
        main.wait_stream(side)
        for t in args:  # memory the main stream frees must not be reused while the side stream still reads it
            if isinstance(t, Tensor):
                t.record_stream(side)
        render.record_stream(main)
        return render[0]

    def _get_outputs_fused(self, camera: Cameras) -> Dict[str, Union[torch.Tensor, List]]:
        """One rasterization of [RGB(SH evaluated), latent] channels (approximate eq. 3, see config)."""
        from gsplat.cuda._wrapper import spherical_harmonics

        viewmat, K, W, H = self._camera_setup(camera)
        d = self._get_downscale_factor()
        camera.rescale_output_resolution(1 / d)
        Kd = camera.get_intrinsics_matrices().to(self.device)
        Wd, Hd = int(camera.width.item()), int(camera.height.item())
        camera.rescale_output_resolution(d)
        self.last_size = (Hd, Wd)
        coeffs = torch.cat((self.features_dc[:, None, :], self.features_rest), dim=1)  # [N, B, 3]
        if self.config.sh_degree > 0:
            deg = min(self.step // self.config.sh_degree_interval, self.config.sh_degree)
            cam_pos = torch.linalg.inv(viewmat[0])[:3, 3]
            dirs = self.means - cam_pos[None]  # as gsplat's rasterization(sh_degree=...) does
            rgb = spherical_harmonics(deg, dirs, coeffs)
            rgb = torch.clamp_min(rgb + 0.5, 0.0)
        else:
            rgb = torch.sigmoid(coeffs[:, 0, :])
        colors = torch.cat([rgb, self.latents], dim=-1)  # [N, 6]
        render, alpha, self.info = self._rasterize(colors, viewmat, Kd, Wd, Hd, absgrad=self.strategy.absgrad)
        self.strategy.step_pre_backward(self.gauss_params, self.optimizers, self.strategy_state, self.step, self.info)
        background = self._get_background_color()
        out_rgb = torch.clamp(render[..., :3] + (1 - alpha) * background, 0.0, 1.0)
        return {
            "rgb": out_rgb.squeeze(0),
            "depth": None,
            "accumulation": alpha.squeeze(0),
            "background": background,
            "latent": render[0, ..., 3:6],
        }

    # ------------------------------------------------------------------ losses
    def get_loss_dict(self, outputs, batch, metrics_dict=None) -> Dict[str, torch.Tensor]:
        loss_dict = super().get_loss_dict(outputs, batch, metrics_dict)
        if self.training and "latent" in outputs and "latent_target" in batch:
            pred = outputs["latent"]  # [h', w', 3]
            target = batch["latent_target"].to(self.device).float()  # [h, w, 3]
            # CLIP targets are valid everywhere: the datamanager says so once (a python bool), saving the mask work
            valid = None if batch.get("latent_all_valid", False) else batch.get("latent_valid")
            h, w = target.shape[:2]
            if pred.shape[:2] != (h, w):
                pred = F.adaptive_avg_pool2d(pred.permute(2, 0, 1)[None], (h, w))[0].permute(1, 2, 0)
            err = ((pred - target) ** 2).sum(-1)  # [h, w]
            if valid is not None:
                v = valid.to(self.device).reshape(h, w).float()
                lat_loss = (err * v).sum() / v.sum().clamp_min(1.0) / 3.0
            else:
                lat_loss = err.mean() / 3.0
            loss_dict["latent_loss"] = self.config.latent_loss_weight * lat_loss
        return loss_dict

    # ------------------------------------------------------------------ text queries
    def text_encoder(self):
        """Callable list[str] -> [T, D] unit text embeddings (label table first, then CLIP text tower)."""
        if self._text_encoder is None:
            from cinenerf_ns.method.semantic_scene import build_text_encoder

            self._text_encoder = build_text_encoder(self.cine_info, self.label_embeddings)
        return self._text_encoder

    def _on_viewer_query(self, element: ViewerText) -> None:
        self._query_text = str(element.value).strip()
        self._query_relevancy = None

    def set_query(self, text: str) -> None:
        self._query_text = text.strip()
        self._query_relevancy = None

    @torch.no_grad()
    def query_relevancy(self) -> Optional[Tensor]:
        """Per-Gaussian relevancy [N] of the current viewer query, or None (no query / no codec)."""
        if not self._query_text or self.codec is None:
            return None
        key = (self.num_points, self.step)  # latents change while training: recompute once per step
        if self._query_relevancy is not None and getattr(self, "_query_key", None) == key:
            return self._query_relevancy
        try:
            enc = self.text_encoder()
            emb = enc([self._query_text, *self.config.relevancy_negatives]).to(self.device)
        except Exception as e:  # viewer must keep running; report once per query
            CONSOLE.print(f"[bold red]CineSplat query failed:[/bold red] {lit(e)}", emoji=False)  # quotes the query
            self._query_text = ""
            return None
        self.codec.to(self.device)
        self._query_relevancy = relevancy_fn(
            self.latents.detach(), self.codec, emb[0], emb[1:], temperature=self.config.relevancy_temperature
        )
        self._query_key = key
        return self._query_relevancy
