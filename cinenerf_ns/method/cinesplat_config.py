"""nerfstudio method specifications ``cinesplat`` and ``cinesplat-lite`` (entry points in pyproject).

Both are splatfacto's recipe (same optimisers, schedules, densification) plus
* the ``latents`` optimizer group (per-Gaussian 3-dim code, eq. 3),
* ``CineSplatDatamanager`` (CLIP / label features -> codec -> per-image latent targets),
* schedules whose checkpointed state holds python floats (loads under torch>=2.6 ``weights_only``).
``cinesplat-lite``: 15k steps, lower feature resolution (48 px long side), one CLIP scale, shorter codec fit: for
quick looks and small GPUs. Both run the latent pass every 2nd step (``latent_every``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Type

from nerfstudio.configs.base_config import ViewerConfig
from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig
from nerfstudio.engine.optimizers import AdamOptimizerConfig
from nerfstudio.engine.trainer import Trainer, TrainerConfig
from nerfstudio.pipelines.base_pipeline import VanillaPipelineConfig
from nerfstudio.plugins.types import MethodSpecification
from nerfstudio.utils.rich_utils import CONSOLE

from cinenerf_ns.console_text import lit
from cinenerf_ns.method.clip_features import ClipFeatureConfig
from cinenerf_ns.method.codec import CodecConfig
from cinenerf_ns.method.config_ranges import check_training_config
from cinenerf_ns.method.datamanager import CineSplatDatamanagerConfig
from cinenerf_ns.method.model import CineSplatModelConfig
from cinenerf_ns.method.schedulers import FloatExponentialDecaySchedulerConfig
from cinenerf_ns.planner.errors import InvalidInputError


@dataclass
class CineSplatTrainerConfig(TrainerConfig):
    """TrainerConfig that tells the datamanager where the run's outputs go (the feature cache lives there)."""

    _target: Type = field(default_factory=lambda: Trainer)

    def __post_init__(self) -> None:
        # ns-train builds this from the command line, then saves config.yml: a bad number stops it before that
        self.check_numbers()

    def check_numbers(self) -> None:
        """The numbers cinesplat adds to ns-train, in range; else one line naming the flag, exit status 2."""
        try:
            check_training_config(self.pipeline.model, self.pipeline.datamanager)
        except InvalidInputError as e:
            CONSOLE.print(f"[bold red]cinesplat:[/bold red] {lit(e)}", emoji=False)
            raise SystemExit(2) from None

    def setup(self, **kwargs):
        self.check_numbers()  # again for `--load-config` (a YAML config is built without __post_init__)
        dm = self.pipeline.datamanager
        if isinstance(dm, CineSplatDatamanagerConfig) and dm.output_dir_hint is None and dm.feature_cache_dir is None:
            # <output_dir>/<experiment>/cinesplat_cache: shared by runs of the same experiment
            dm.output_dir_hint = self.get_base_dir().parent.parent
        return super().setup(**kwargs)


def _optimizers(max_steps: int) -> dict:
    return {
        "means": {
            "optimizer": AdamOptimizerConfig(lr=1.6e-4, eps=1e-15),
            "scheduler": FloatExponentialDecaySchedulerConfig(lr_final=1.6e-6, max_steps=max_steps),
        },
        "features_dc": {"optimizer": AdamOptimizerConfig(lr=0.0025, eps=1e-15), "scheduler": None},
        "features_rest": {"optimizer": AdamOptimizerConfig(lr=0.0025 / 20, eps=1e-15), "scheduler": None},
        "opacities": {"optimizer": AdamOptimizerConfig(lr=0.05, eps=1e-15), "scheduler": None},
        "scales": {"optimizer": AdamOptimizerConfig(lr=0.005, eps=1e-15), "scheduler": None},
        "quats": {"optimizer": AdamOptimizerConfig(lr=0.001, eps=1e-15), "scheduler": None},
        # per-Gaussian semantic code; codes live in [-1, 1] (codec tanh), targets change slowly
        "latents": {"optimizer": AdamOptimizerConfig(lr=0.005, eps=1e-15), "scheduler": None},
        "camera_opt": {
            "optimizer": AdamOptimizerConfig(lr=1e-4, eps=1e-15),
            "scheduler": FloatExponentialDecaySchedulerConfig(
                lr_final=5e-7, max_steps=max_steps, warmup_steps=1000, lr_pre_warmup=0
            ),
        },
        "bilateral_grid": {
            "optimizer": AdamOptimizerConfig(lr=2e-3, eps=1e-15),
            "scheduler": FloatExponentialDecaySchedulerConfig(
                lr_final=1e-4, max_steps=max_steps, warmup_steps=1000, lr_pre_warmup=0
            ),
        },
    }


def make_cinesplat_config(lite: bool = False) -> CineSplatTrainerConfig:
    max_steps = 15000 if lite else 30000
    clip = ClipFeatureConfig(input_long_sides=(448,), feature_long_side=48) if lite else ClipFeatureConfig()
    codec = CodecConfig(train_steps=800) if lite else CodecConfig()
    return CineSplatTrainerConfig(
        method_name="cinesplat-lite" if lite else "cinesplat",
        steps_per_eval_image=100,
        steps_per_eval_batch=0,
        steps_per_save=2000,
        steps_per_eval_all_images=1000,
        max_num_iterations=max_steps,
        mixed_precision=False,
        pipeline=VanillaPipelineConfig(
            datamanager=CineSplatDatamanagerConfig(
                dataparser=NerfstudioDataParserConfig(load_3D_points=True),
                cache_images_type="uint8",
                clip=clip,
                codec=codec,
            ),
            model=CineSplatModelConfig(),
        ),
        optimizers=_optimizers(max_steps),
        viewer=ViewerConfig(num_rays_per_chunk=1 << 15),
        vis="viewer",
    )


cinesplat = MethodSpecification(
    config=make_cinesplat_config(lite=False),
    description="Cine-NeRF splat: splatfacto + distilled 3-dim CLIP latent per Gaussian (text queries)",
)

cinesplat_lite = MethodSpecification(
    config=make_cinesplat_config(lite=True),
    description="cinesplat, cheaper: 15k steps, 48 px feature maps, one CLIP scale",
)
