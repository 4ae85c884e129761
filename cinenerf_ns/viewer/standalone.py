"""``cinesplat-viewer``: the cinematography panel on a plain viser server, no GPU needed.

The splat is drawn client-side by the browser (viser's Gaussian-splat node); planning runs on CPU.

    cinesplat-viewer --load-config outputs/<run>/cinesplat/<ts>/config.yml
    cinesplat-viewer --load-config scene.ply          # a 3DGS / splatfacto-export .ply
    cinesplat-viewer --load-config demo               # built-in labelled demo scene

Targets can always be typed as coordinates "x y z" (scene units). Text queries need a semantic
``locate`` (trained cinesplat latents + codec + text encoder); the demo scene answers its own object
names. The planner is ``cinenerf_ns.planner.planner.Planner`` when importable, else the straight-line
stand-in from :mod:`.demo` (the status line says which one ran).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, Optional, Tuple

import numpy as np

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene import EllipsoidScene, SceneConfig, quat_wxyz_to_rotmat

from .backend import FunctionBackend, LocateFn, PlanFn, SceneGaussians, label_locate, to_numpy
from .conventions import VISER_NERFSTUDIO_SCALE_RATIO

SH_C0 = 0.28209479177387814  # degree-0 spherical-harmonic constant (3DGS colour = 0.5 + C0 * f_dc)


@dataclass
class SplatParams:
    """Raw splat parameters as 3DGS / splatfacto store them (numpy, scene units)."""

    means: np.ndarray  # [N, 3]
    quats_wxyz: np.ndarray  # [N, 4]
    log_scales: np.ndarray  # [N, 3]
    opacity_logits: np.ndarray  # [N]
    colors: np.ndarray  # [N, 3] RGB in [0, 1]

    def display_gaussians(self) -> SceneGaussians:
        rot = quat_wxyz_to_rotmat(_t(self.quats_wxyz)).numpy()  # [N, 3, 3]
        s2 = np.exp(2.0 * self.log_scales.astype(np.float64))  # [N, 3]
        cov = (rot * s2[:, None, :]) @ np.swapaxes(rot, -1, -2)  # [N, 3, 3]
        return SceneGaussians(self.means, self.colors, 1 / (1 + np.exp(-self.opacity_logits)), cov)


def _t(x):
    import torch

    return torch.as_tensor(np.asarray(x, np.float64))


@dataclass
class LoadedScene:
    splat: SplatParams
    name: str
    data_dir: Path
    config_path: Optional[Path] = None
    locate: Optional[LocateFn] = None
    default_goto: str = ""
    default_look_at: str = ""


# --------------------------------------------------------------------------------------- loading
def load_ply(path: Path) -> SplatParams:
    """Read a 3DGS-layout .ply (x y z, f_dc_0..2, opacity, scale_0..2, rot_0..3: nerfstudio's
    splatfacto export and the original 3DGS writer)."""
    from plyfile import PlyData

    ply = PlyData.read(str(path))
    v = ply["vertex"].data
    names = set(v.dtype.names)
    need = {"x", "y", "z", "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"}
    if not need <= names:
        raise InvalidInputError(
            f"{path} is not a Gaussian-splat .ply (missing {sorted(need - names)}); export one with "
            f"`ns-export gaussian-splat` or pass the run's config.yml"
        )
    col = lambda *k: np.stack([np.asarray(v[c], np.float32) for c in k], -1)
    if {"f_dc_0", "f_dc_1", "f_dc_2"} <= names:
        colors = np.clip(0.5 + SH_C0 * col("f_dc_0", "f_dc_1", "f_dc_2"), 0, 1)
    elif {"red", "green", "blue"} <= names:
        colors = col("red", "green", "blue") / 255.0
    else:
        colors = np.full((len(v), 3), 0.7, np.float32)
    return SplatParams(
        col("x", "y", "z"), col("rot_0", "rot_1", "rot_2", "rot_3"), col("scale_0", "scale_1", "scale_2"),
        np.asarray(v["opacity"], np.float32), colors.astype(np.float32),
    )


def load_checkpoint(config_path: Path) -> Tuple[SplatParams, Path]:
    """Splat parameters of a splatfacto / cinesplat run from its config.yml (newest checkpoint),
    plus the dataset directory (where the Render tab keeps camera_paths/)."""
    import torch
    import yaml

    config = yaml.load(config_path.read_text(), Loader=yaml.Loader)  # nerfstudio's own loader (trusted local file)
    ckpt_dir = config_path.parent / "nerfstudio_models"
    if not ckpt_dir.exists():
        ckpt_dir = Path(config.get_checkpoint_dir())
    ckpts = sorted(ckpt_dir.glob("step-*.ckpt"), key=lambda p: int(p.stem.split("-")[1]))
    if not ckpts:
        raise InvalidInputError(f"no step-*.ckpt checkpoint in {ckpt_dir}")
    # weights_only=False: nerfstudio checkpoints hold optimizer/scaler state (the user's own file).
    state = torch.load(ckpts[-1], map_location="cpu", weights_only=False)["pipeline"]
    state = {k.replace("module.", "", 1) if k.startswith("module.") else k: v for k, v in state.items()}
    key = lambda n: state[f"_model.gauss_params.{n}"].float().numpy()
    try:
        means, quats, scales, opac, dc = key("means"), key("quats"), key("scales"), key("opacities"), key("features_dc")
    except KeyError as err:
        raise InvalidInputError(f"{ckpts[-1]} is not a Gaussian-splat checkpoint (missing {err})") from err
    data = getattr(config, "data", None) or getattr(config.pipeline.datamanager, "data", None) or Path(".")
    data = Path(data)
    data = data.parent if data.is_file() else data
    colors = np.clip(0.5 + SH_C0 * dc.reshape(-1, 3), 0, 1).astype(np.float32)
    return SplatParams(means, quats, scales, opac.reshape(-1), colors), data


def load_scene(source: str, data_dir: Optional[Path] = None) -> LoadedScene:
    if source == "demo":
        from .demo import demo_scene

        d = demo_scene()
        splat = SplatParams(d.means, d.quats_wxyz, d.log_scales, d.opacity_logits, d.colors)
        return LoadedScene(
            splat, "demo", data_dir or Path("demo_output") / "cinesplat-viewer-demo", None,
            locate=label_locate(d.means, d.labels, d.label_of), default_goto="red box", default_look_at="blue pillar",
        )
    path = Path(source)
    if not path.exists():
        raise InvalidInputError(f"--load-config {source}: no such file (give a config.yml, a .ply or 'demo')")
    if path.suffix.lower() == ".ply":
        return LoadedScene(load_ply(path), path.stem, data_dir or path.parent, None)
    if path.suffix.lower() in (".yml", ".yaml"):
        splat, data = load_checkpoint(path)
        return LoadedScene(splat, data.name, data_dir or data, path.absolute())
    raise InvalidInputError(f"--load-config {source}: expected a config.yml, a .ply or 'demo'")


# --------------------------------------------------------------------------------------- planner
def make_plan_fn(scene: EllipsoidScene, planner: str = "auto") -> Tuple[PlanFn, str]:
    """The real planner when importable (``planner='auto'|'real'``), else the straight-line stand-in."""
    if planner in ("auto", "real"):
        try:
            import torch

            from cinenerf_ns.planner.planner import Planner  # type: ignore

            real = Planner(scene)
            if hasattr(real, "prepare"):
                real.prepare()

            def plan(goal, look_at, start=None, seed=0, n_candidates=1):
                t = lambda x: None if x is None else torch.as_tensor(np.asarray(x), dtype=scene.dtype, device=scene.device)
                return real.plan(t(goal), t(look_at), start=t(start), seed=seed, n_candidates=n_candidates)

            return plan, "cinenerf_ns planner"
        except ImportError:
            if planner == "real":
                raise
    from .demo import StraightLinePlanner

    stand_in = StraightLinePlanner.from_scene(scene)
    return stand_in.plan, "straight-line stand-in planner"


# --------------------------------------------------------------------------------------- viewer
@dataclass
class StandaloneConfig:
    """cinesplat-viewer: plan, watch and export camera paths in the browser, no GPU needed."""

    load_config: str = "demo"
    """A run's config.yml, a Gaussian-splat .ply, or 'demo' (built-in labelled scene)."""
    port: int = 7007
    """Port of the viewer (open http://localhost:<port>)."""
    host: str = "0.0.0.0"
    """Interface to listen on (0.0.0.0: all, like ns-viewer)."""
    data: Optional[Path] = None
    """Where camera_paths/ go (default: the run's dataset directory, or the .ply's directory)."""
    planner: str = "auto"
    """'auto' (the cinenerf_ns planner if importable, else the straight-line stand-in), 'real', 'straight'."""
    camera_radius: float = 0.03
    """Camera body radius in scene units (obstacle model)."""
    n_candidates: int = 3
    """Default number of candidate shots per Plan."""
    max_display_gaussians: int = 1_000_000
    """Draw at most this many Gaussians in the browser (highest opacity first); planning uses all."""
    scale: float = VISER_NERFSTUDIO_SCALE_RATIO
    """viser units per scene unit (nerfstudio's viewer uses 10)."""


class StandaloneViewer:
    """A running standalone viewer (server + panel); ``close()`` stops it."""

    def __init__(self, cfg: StandaloneConfig, locate: Optional[LocateFn] = None,
                 plan_fn: Optional[PlanFn] = None) -> None:
        import viser

        from .panel import PanelConfig
        from .viser_ui import attach_cine_panel

        t0 = time.perf_counter()
        self.cfg = cfg
        self.loaded = load_scene(cfg.load_config, cfg.data)
        sp = self.loaded.splat
        self.obstacles = EllipsoidScene.from_splat(
            _t(sp.means).float(), _t(sp.quats_wxyz).float(), _t(sp.log_scales).float(), _t(sp.opacity_logits).float(),
            SceneConfig(camera_radius=cfg.camera_radius),
        )
        if plan_fn is None:
            plan_fn, planner_name = make_plan_fn(self.obstacles, cfg.planner)
        else:
            planner_name = "injected planner"
        self.planner_name = planner_name
        display = sp.display_gaussians()
        self.backend = FunctionBackend(display, plan_fn, locate or self.loaded.locate, self.loaded.name, planner_name)
        self.server = viser.ViserServer(host=cfg.host, port=cfg.port, verbose=False)
        self.server.scene.set_up_direction("+z")
        self._draw_splat(display)
        self.panel = attach_cine_panel(
            self.server, self.backend,
            PanelConfig(data_dir=self.loaded.data_dir, config_path=self.loaded.config_path, n_candidates=cfg.n_candidates),
            scale=cfg.scale, default_goto=self.loaded.default_goto, default_look_at=self.loaded.default_look_at,
        )
        self.ui = self.panel.view
        lo, hi = np.percentile(display.means, 2, axis=0), np.percentile(display.means, 98, axis=0)
        self._home_target = (lo + hi) / 2 * cfg.scale
        self._home_position = ((lo + hi) / 2 + np.array([1.0, -1.2, 0.9]) * (hi - lo).max()) * cfg.scale

        @self.server.on_client_connect
        def _(client) -> None:
            client.camera.position = self._home_position
            client.camera.look_at = self._home_target

        self.panel._set_status(
            f"Loaded '{self.loaded.name}': {len(display)} Gaussians ({len(self.obstacles)} obstacles) in "
            f"{time.perf_counter() - t0:.1f} s. Planner: {planner_name}"
            f"{' (cinenerf_ns.planner.planner not importable)' if 'stand-in' in planner_name and cfg.planner == 'auto' else ''}. "
            f"{'Text queries: object names.' if self.backend._locate_fn else 'Type targets as x y z.'}",
            "info",
        )

    def _draw_splat(self, g: SceneGaussians) -> None:
        n = len(g)
        idx = np.arange(n)
        if n > self.cfg.max_display_gaussians:
            idx = np.argsort(-g.opacities)[: self.cfg.max_display_gaussians]
        s = self.cfg.scale
        self.server.scene.add_gaussian_splats(
            "/splat", centers=(g.means[idx] * s).astype(np.float32),
            covariances=(g.covariances[idx] * s * s).astype(np.float32),
            rgbs=g.colors[idx].astype(np.float32), opacities=g.opacities[idx, None].astype(np.float32),
        )

    @property
    def url(self) -> str:
        return f"http://localhost:{self.server.get_port()}"

    def close(self) -> None:
        self.panel.close()
        self.server.stop()


def main(cfg: StandaloneConfig) -> None:
    from rich.console import Console

    viewer = StandaloneViewer(cfg)
    Console().print(f"[bold green]cinesplat-viewer[/] running at {viewer.url}  (Ctrl+C to stop)\n{viewer.panel.status}")
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()


def entrypoint() -> None:
    import tyro

    main(tyro.cli(StandaloneConfig))


if __name__ == "__main__":
    entrypoint()
