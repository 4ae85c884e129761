"""Full-image datamanager that also feeds each training image's latent target f_enc(P) [h, w, 3].

Before training (``test_mode == "val"``, i.e. ns-train) it
1. computes (or reuses from the on-disk cache) the per-image D-dim feature maps of the train images, from
   CLIP (``feature_source="clip"``) or from label masks (``feature_source="labels"``),
2. fits the codec (eq. 2) on them,
3. encodes every feature map once to a 3-channel latent target kept next to the cached image,
4. publishes the codec weights + info in ``train_dataset.metadata`` for the model (saved in its checkpoint).
In ns-render / ns-viewer (test modes "test"/"inference") none of this runs: the checkpoint has it all.

Label-mask layout (``feature_source="labels"``):
    <data>/labels/<image_stem>.png   integer label id per pixel (8- or 16-bit PNG, or .npy), any resolution
                                     (resized nearest-neighbour to the feature map)
    <data>/labels.json               {"0": "floor", "1": "palm tree", ...}  id -> name
Pixels whose id is not in labels.json are ignored by the latent loss.
"""

from __future__ import annotations

from copy import deepcopy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Literal, Optional, Tuple, Type

import torch
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.data.datamanagers.full_images_datamanager import FullImageDatamanager, FullImageDatamanagerConfig
from nerfstudio.utils.rich_utils import CONSOLE

from cinenerf_ns.console_text import lit
from cinenerf_ns.method.clip_features import ClipFeatureConfig
from cinenerf_ns.method.codec import CodecConfig
from cinenerf_ns.method.compat import patch_ply_loader_without_open3d
from cinenerf_ns.method.model import META_CODEC_STATE, META_INFO

# splatfacto's seed points (transforms.json `ply_file_path`) load without open3d (see compat.py)
patch_ply_loader_without_open3d()


@dataclass
class CineSplatDatamanagerConfig(FullImageDatamanagerConfig):
    """FullImageDatamanager + per-image semantic latent targets for cinesplat."""

    _target: Type = field(default_factory=lambda: CineSplatDatamanager)
    feature_source: Literal["clip", "labels"] = "clip"
    """Where the per-pixel features come from: dense CLIP image features, or label masks whose names are
    embedded with the CLIP text tower (layout: <data>/labels/<image_stem>.png + <data>/labels.json)."""
    clip: ClipFeatureConfig = field(default_factory=ClipFeatureConfig)
    """CLIP model (image features and text queries) and dense-feature settings."""
    codec: CodecConfig = field(default_factory=CodecConfig)
    """Feature codec (eq. 2) architecture and training."""
    labels_dir: str = "labels"
    """Folder (relative to the data folder, or absolute) holding one label map per image."""
    labels_json: str = "labels.json"
    """File (relative to the data folder, or absolute) mapping label id -> name."""
    feature_cache_dir: Optional[Path] = None
    """Where cached feature maps go. None: <output_dir>/cinesplat_cache when known, else <data>/.cinesplat_cache."""
    output_dir_hint: Optional[Path] = None
    """Set by the trainer glue (cinesplat_config) to the experiment's output folder, to cache next to outputs."""


class CineSplatDatamanager(FullImageDatamanager):
    """Adds ``latent_target`` [h, w, 3], ``latent_valid`` [h, w, 1] and ``latent_all_valid`` (bool) to every
    training batch."""

    config: CineSplatDatamanagerConfig

    def __init__(self, config: CineSplatDatamanagerConfig, device="cpu", test_mode="val", world_size=1, local_rank=0,
                 **kwargs):
        super().__init__(config, device=device, test_mode=test_mode, world_size=world_size, local_rank=local_rank,
                         **kwargs)
        self.latent_targets: List[torch.Tensor] = []  # per train image [h, w, 3]
        self.latent_valid: List[torch.Tensor] = []  # per train image [h, w, 1] bool
        self.latent_all_valid: List[bool] = []  # per train image: every pixel valid (the loss then skips the mask)
        self.semantic_stats: Dict = {}
        if test_mode == "val":
            self._prepare_semantics()

    # ------------------------------------------------------------------
    def _cache_dir(self) -> Path:
        if self.config.feature_cache_dir is not None:
            return Path(self.config.feature_cache_dir)
        if self.config.output_dir_hint is not None:
            return Path(self.config.output_dir_hint) / "cinesplat_cache"
        data = Path(self.config.dataparser.data)
        base = data if data.is_dir() else data.parent
        return base / ".cinesplat_cache"

    def _prepare_semantics(self) -> None:
        from cinenerf_ns.method.clip_features import ClipWeightsError
        from cinenerf_ns.method.feature_cache import prepare_semantic_targets
        from cinenerf_ns.method.label_features import LabelDataError

        outs = self.train_dataparser_outputs
        image_paths = [Path(p) for p in outs.image_filenames]
        data = Path(self.config.dataparser.data)
        data_dir = data if data.is_dir() else data.parent
        # features come from the images exactly as training sees them (after nerfstudio's undistortion)
        cached = self.cached_train
        sizes = [(int(d["image"].shape[0]), int(d["image"].shape[1])) for d in cached]
        images = [(lambda i=i: cached[i]["image"]) for i in range(len(cached))]
        label_transform, label_key = self._label_transform()
        try:
            result = prepare_semantic_targets(
                images=images,
                image_paths=image_paths,
                image_sizes=sizes,
                source=self.config.feature_source,
                clip_config=self.config.clip,
                codec_config=self.config.codec,
                cache_dir=self._cache_dir(),
                data_dir=data_dir,
                labels_dir=self.config.labels_dir,
                labels_json=self.config.labels_json,
                device=self.device,
                log=lambda m: CONSOLE.print(m, markup=False, emoji=False),  # messages quote paths
                label_transform=label_transform,
                label_transform_key=label_key,
            )
        except (ClipWeightsError, LabelDataError) as e:
            # one clear message, no stack trace of a download failure
            CONSOLE.print(f"[bold red]cinesplat:[/bold red] {lit(e)}", emoji=False)
            raise SystemExit(2) from None
        self.semantic_stats = result.stats
        self.latent_targets = [t.to(self.device) for t in result.latent_targets]
        self.latent_valid = [v.to(self.device) for v in result.latent_valid]
        self.latent_all_valid = [bool(v.all()) for v in result.latent_valid]  # once, on the CPU copies
        meta = self.train_dataset.metadata
        meta[META_CODEC_STATE] = {k: v.detach().cpu() for k, v in result.codec.state_dict().items()}
        meta[META_INFO] = result.info
        if result.label_embeddings is not None:
            meta["label_embeddings"] = result.label_embeddings.cpu()
        CONSOLE.print(
            f"[bold green]cinesplat:[/] {len(self.latent_targets)} latent targets "
            f"{tuple(self.latent_targets[0].shape)} ready; codec 1-cos {result.stats['error_after']:.4f} "
            f"(from {result.stats['error_before']:.4f}) in {result.stats['seconds']:.1f}s"
        )

    def _label_transform(self):
        """Label maps -> the training images' geometry: resize (nearest) to the camera's original size, then
        undistort + crop exactly like nerfstudio undistorts the images (perspective cameras)."""
        import numpy as np
        from nerfstudio.cameras.cameras import CameraType

        from cinenerf_ns.method.label_features import resize_labels, undistort_label_map

        cams = deepcopy(self.train_dataparser_outputs.cameras)  # before the datamanager's in-place undistortion
        cams.rescale_output_resolution(scaling_factor=self.config.camera_res_scale_factor)

        def transform(i: int, ids: torch.Tensor) -> torch.Tensor:
            cam = cams[i]
            ids = resize_labels(ids, (int(cam.height.item()), int(cam.width.item())))
            dist = cam.distortion_params
            if dist is None or not bool(torch.any(dist != 0)):
                return ids
            if cam.camera_type.item() != CameraType.PERSPECTIVE.value:
                raise SystemExit("cinesplat: label masks with distorted non-perspective cameras are not supported")
            return undistort_label_map(ids, cam.get_intrinsics_matrices().numpy(), dist.numpy())

        dist = cams.distortion_params
        key = "none" if dist is None else str(np.round(dist.numpy(), 8).tolist())
        return transform, key

    def next_train(self, step: int) -> Tuple[Cameras, Dict]:
        camera, data = super().next_train(step)
        if self.latent_targets:
            idx = int(camera.metadata["cam_idx"])  # type: ignore[index]
            data["latent_target"] = self.latent_targets[idx]
            data["latent_valid"] = self.latent_valid[idx]
            data["latent_all_valid"] = self.latent_all_valid[idx] if self.latent_all_valid else False
        return camera, data
