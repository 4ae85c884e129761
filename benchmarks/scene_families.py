"""Scene families and request starts for the planner benchmarks (issue 23: benchmarks that cannot flatter).

    --family procedural   planner/scene/procedural.py's room (z up, 2 x 2 x 1, thin discs, 6 objects on a jittered grid)
    --family blobs        synthetic/blobs.py (y up, about [-1, 1]^3, 3 walls + floor, random round blobs, floaters)
    --family grove[:BG:FF]  synthetic/grove.py (z up, open: ground, 36 thin trunks + canopies, rocks, 3% faint floaters,
                          3% huge Gaussians on a far background shell; no training cameras) with seeded start / go-to
                          pairs whose reachability and length come from a fine-grid reference search (GROVE_SPACING)
    --family fox          ../shared/data/fox_cinesplat/fox3000.npz (a real capture's compact export)
    --family scene:SPEC   any scene every command reads (cinenerf_ns.scenes.load_scene: config.yml, run folder, .ckpt,
                          compact .npz / .pt, 3DGS .ply, procedural:N); ply:PATH / npz:PATH say the same
The files go through cinenerf_ns.scenes.load_scene (the loader of every command: the same obstacles) and their
start_region (the training cameras' box; None for a .ply) defines the planning region. Targets: procedural / blobs:
go-to an object's centre +- jitter inside it, look-at another object's centre; files: uniform in the start region (the
planning region when there is none).

    --start-mode random   the planner samples each request's start (seeded), as the viewer does
    --start-mode given    explicit starts drawn seeded before timing: uniform in the start region (else the planning
                          region), >= GIVEN_CLEAR from every Gaussian centre, >= GIVEN_FROM_GOAL from the go-to target,
                          and accepted by Planner.checked_start (free by the planner's own checks)
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, List, Optional, Tuple

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
FOX = next((p for p in (REPO.parent / "shared" / "data" / "fox_cinesplat" / "fox3000.npz",  # beside the checkout
                         REPO.parents[1] / "shared" / "data" / "fox_cinesplat" / "fox3000.npz")  # beside a worktree
            if p.exists()), REPO.parent / "shared" / "data" / "fox_cinesplat" / "fox3000.npz")
FAMILIES = "procedural | blobs | grove[:BG:FF] | fox | scene:SPEC (ply:PATH, npz:PATH)"
GROVE_SPACING = 0.025  # scene units: the grove reference grid's spacing (synthetic/grove.py reference_search)
GIVEN_CLEAR = 0.1  # scene units: a given start's distance to every Gaussian centre
GIVEN_FROM_GOAL = 0.5  # scene units: a given start's distance to its go-to target


@dataclass
class Family:
    name: str  # the --family spec as given
    kind: str  # "procedural" | "blobs" | "file"
    scene: object  # EllipsoidScene on the requested device
    start_region: Optional[Tuple[np.ndarray, np.ndarray]]  # (lo [3], hi [3]) for PlannerConfig.start_region, or None
    up: Tuple[float, float, float]  # PlannerConfig.up
    objects: list  # [(centre [3], size [3])] go-to / look-at objects (procedural, blobs); [] for files
    description: str
    pairs: list = field(default_factory=list)  # grove: [GrovePair] (start, go-to, look-at, reference length)

    def targets(self, rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """One request's (go-to [3], look-at [3]); lo / hi [3]: where file families draw them (the grove: a random
        pair's)."""
        if self.pairs:
            p = self.pairs[int(rng.integers(len(self.pairs)))]
            return p.goal.copy(), p.look_at.copy()
        if self.objects:
            i, j = rng.choice(len(self.objects), 2, replace=False)
            c, size = self.objects[i]
            return c + rng.uniform(-0.25, 0.25, 3) * size, self.objects[j][0].copy()
        return rng.uniform(lo, hi), rng.uniform(lo, hi)


def load_family(spec: str, n_gaussians: int, seed: int, device: str = "cpu", n_pairs: int = 100) -> Family:
    """--family spec -> Family (n_gaussians / seed only for the generated families, n_pairs for the grove's)."""
    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
    from cinenerf_ns.planner.scene.scene_config import SceneConfig

    dev = torch.device(device)
    if spec == "procedural":
        from cinenerf_ns.planner.scene.procedural import procedural_room

        room = procedural_room(n_gaussians, seed=seed)
        scene = EllipsoidScene.from_splat(room.means.to(dev), room.quats.to(dev), room.log_scales.to(dev),
                                          room.opacity_logits.to(dev))
        r = float(scene.camera_radius)
        return Family(spec, "procedural", scene, (room.free_lo + r, room.free_hi - r), (0.0, 0.0, 1.0),
                      [(o.center, o.size) for o in room.objects], f"procedural_room N={len(scene)} seed {seed}")
    if spec == "blobs":
        from cinenerf_ns.synthetic.blobs import blob_scene

        b = blob_scene(n_gaussians, seed=seed)
        scene = EllipsoidScene.from_params(b.splat, device=dev)
        r = float(scene.camera_radius)
        return Family(spec, "blobs", scene, (b.free_lo + r, b.free_hi - r), b.up,
                      [(x.center, np.full(3, 2 * x.radius)) for x in b.blobs], f"blob_scene N={len(scene)} seed {seed}")
    if spec == "grove" or spec.startswith("grove:"):
        from cinenerf_ns.planner.scene.spatial_index import GridIndex
        from cinenerf_ns.synthetic.grove import grove_pairs, grove_scene

        try:  # grove:BACKGROUND:FLOATERS fractions (default 0.03 each)
            fr = [float(v) for v in spec.split(":")[1:]] if ":" in spec else []
            g = grove_scene(n_gaussians, seed=seed, **dict(zip(("background_fraction", "floater_fraction"), fr)))
        except (ValueError, TypeError) as e:
            raise SystemExit(f"--family {spec!r}: expected grove or grove:BACKGROUND:FLOATERS ({e})") from e
        scene = EllipsoidScene.from_params(g.splat, device=dev)
        pairs, ref = grove_pairs(g, scene, GridIndex.build(scene), n_pairs, seed=seed, spacing=GROVE_SPACING)
        n_ref = sum(p.reference_length is not None for p in pairs)
        return Family(spec.replace(":", "_"), "grove", scene, None, g.up, [],
                      f"grove_scene N={len(scene)} seed {seed} ({n_ref}/{len(pairs)} pairs joined by the reference "
                      f"grid {list(ref.free.shape)} at {ref.spacing:g})", pairs=pairs)
    if spec == "fox":
        source = str(FOX)
    elif spec.startswith(("scene:", "ply:", "npz:")):
        source = spec.split(":", 1)[1]
    else:
        raise SystemExit(f"--family {spec!r}: expected {FAMILIES}")
    from cinenerf_ns.planner.errors import PlanningError
    from cinenerf_ns.scenes import load_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the loader's splat-repair summary
        try:
            loaded = load_scene(source, SceneConfig(), device=device)
        except (PlanningError, ValueError) as e:  # not found, unreadable (InvalidInputError, CheckpointError)
            raise SystemExit(f"--family {spec}: {e}") from None
    return Family(spec, "file", loaded.scene, loaded.start_region, (0.0, 0.0, 1.0), [],
                  f"{Path(source).name} ({len(loaded.scene)} Gaussians)")


def given_starts(planner, goals: List[np.ndarray], region: Tuple[np.ndarray, np.ndarray], seed: int,
                 max_tries: int = 20_000) -> List[np.ndarray]:
    """One explicit start [3] per go-to target (see the module docstring), drawn seeded; the planner is prepared."""
    from scipy.spatial import cKDTree

    from cinenerf_ns.planner.errors import PlanningError

    tree = cKDTree(planner.scene.means.detach().cpu().double().numpy())
    rng = np.random.default_rng(10_007 + seed)
    lo, hi = (np.asarray(v, dtype=np.float64) for v in region)
    out = []
    for g in goals:
        for _ in range(max_tries):
            s = rng.uniform(lo, hi)
            if np.linalg.norm(s - g) < GIVEN_FROM_GOAL or tree.query(s)[0] < GIVEN_CLEAR:
                continue
            try:
                out.append(planner.checked_start(s))
                break
            except PlanningError:
                continue
        else:
            raise SystemExit(f"no given start found for goal {np.round(g, 3).tolist()} in {max_tries} tries")
    return out


def request_fn(planner, start_mode: str) -> Callable:
    """plan(goal, look, start, seed) -> shots for the start mode (the start is ignored for 'random')."""
    if start_mode == "given":
        return lambda g, la, s, seed: planner.plan(g, la, start=s, seed=seed)
    return lambda g, la, s, seed: planner.plan(g, la, seed=seed)
