"""Scenes for planning: a scene file or spec -> obstacles, a text locator and a start region; text or 'x y z' -> a
target point. The command line and both viewers load scenes here (one loader, the same obstacles and semantics)."""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

from cinenerf_ns.method.training_cameras import camera_box, run_config_path, scene_camera_centres, scene_camera_poses
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.file_checks import path_problem
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.scene.splat_params import NO_COLOUR_GREY, SplatParams, rgb_to_dc
from cinenerf_ns.point_text import parse_point
from cinenerf_ns.semantic_defaults import CENTRE_RELEVANCY, OBJECT_CLUSTER, SMOOTH_NEIGHBORS

ASSETS = Path(__file__).parent / "assets"
DEMO_SCENE = ASSETS / "room0.npz"  # the bundled trained room (make demo, cinesplat-viewer's 'demo')

_STOP_WORDS = {"the", "a", "an", "to", "at", "of", "go", "look", "on", "in"}


def _forms(w: str) -> frozenset:
    """A word and the singulars it may be the plural of: 'lamps' {lamp}, 'vases' {vase, vas}, 'boxes' {box, boxe},
    'shelves' {shelf, shelve, shelv}, 'bodies' {body}; 'glass' and words of 3 letters or fewer ('bus') only themselves.
    Two words match when their forms meet: a word always matches itself, and 'lamps' matches 'lamp'."""
    out = {w}
    if len(w) > 3 and w.endswith("s") and not w.endswith("ss"):
        out.add(w[:-1])
        if w.endswith("es"):
            out.add(w[:-2])
        if w.endswith("ies"):
            out.add(w[:-3] + "y")
        if w.endswith("ves"):
            out.update((w[:-3] + "f", w[:-3] + "fe"))
    return frozenset(out)


def _words(text: str) -> List[str]:
    """Lower-case words: runs of letters and digits of any script."""
    return re.findall(r"[^\W_]+", text.casefold())


def word_matches(query: str, names: List[str]) -> List[int]:
    """Indices of the names that hold every word of the query, stop words ('the', 'go', 'to', ...) aside. Whole words
    only, singular or plural (_forms): 'lamp' and 'lamps' -> 'floor lamp', 'armchair' -> 'red armchair'; a part of a
    word is not a match ('chair' and 'hair' name no 'red armchair', 'ant' no 'potted plant'), nor a shared adjective
    with other words ('purple elephant' names no 'purple stool'). Empty when the query has no words."""
    q = [_forms(w) for w in _words(query) if w not in _STOP_WORDS]
    if not q:
        return []
    hits = []
    for i, n in enumerate(names):
        forms = frozenset().union(*(_forms(w) for w in _words(n)))
        if all(f & forms for f in q):
            hits.append(i)
    return hits


def _word_match(query: str, names: List[str]) -> Optional[int]:
    """Index of the name word_matches picks (ties: the fewest words, then the first: 'lamp' of 'floor lamp' and
    'floor lamp stand' is 'floor lamp'; the caller's description names it); None when no name holds every word."""
    hits = word_matches(query, names)
    return min(hits, key=lambda i: len(_words(names[i]))) if hits else None


def free_text(info: Dict[str, Any]) -> bool:
    """Whether free text means anything to a scene: its CLIP text tower has real weights. Scenes trained with random
    weights (tests, offline runs) or without a CLIP spec answer only their own label names."""
    clip = info.get("clip") or {}
    return bool(clip) and not clip.get("random_weights", False)


def procedural_object(room: Any, text: str) -> int:
    """Index of the procedural room's object a text names (whole words, see word_matches)."""
    names = [o.name for o in room.objects]
    i = _word_match(text, names)
    if i is None:
        raise InvalidInputError(f"no object matches '{text}' in the procedural room (a name must hold each of its "
                                f"words, whole words); objects: {', '.join(names)}")
    return i


def label_query(text: str, label_names: List[str], free: bool = True) -> str:
    """The text a semantic scene is queried with: a query naming one of the scene's labels (every word in it, whole
    words, see word_matches) is mapped to that label (its stored embedding needs no CLIP weights); other text goes to
    the CLIP text tower when ``free`` (free_text), else InvalidInputError listing what the scene can answer."""
    q = text.strip()
    lower = [n.lower() for n in label_names]
    if q.lower() in lower:
        return label_names[lower.index(q.lower())]
    i = _word_match(q, label_names) if label_names else None
    if i is not None:
        return label_names[i]
    if free:
        return q
    if label_names:
        raise InvalidInputError(
            f"nothing in the scene matches '{q}': this scene answers only its own object names, whole words (it was "
            f"trained without real CLIP weights): {', '.join(label_names)}; or give a point 'x y z'")
    raise InvalidInputError(
        f"'{q}' cannot be looked up: this scene has no object names and its CLIP features come from random weights, "
        f"so text means nothing to it; give the target as a point 'x y z'")


PROCEDURAL_N = (1000, 2_000_000)  # Gaussians a procedural:N room may have


def procedural_spec(spec: str) -> Optional[Tuple[int, int]]:
    """(N, SEED) of 'procedural', 'procedural:N' or 'procedural:N:SEED'; None for anything not starting with
    'procedural:' (a file such as procedural_room.ply); InvalidInputError for a malformed procedural spec."""
    if spec != "procedural" and not spec.startswith("procedural:"):
        return None
    m = re.fullmatch(r"procedural(?::([0-9]{1,9})(?::([0-9]{1,18}))?)?", spec)
    lo, hi = PROCEDURAL_N
    if m is None or not lo <= int(m.group(1) or 20_000) <= hi:
        raise InvalidInputError(f"bad procedural scene {spec!r}: give procedural, procedural:N or procedural:N:SEED "
                                f"with N a whole number in [{lo}, {hi}] and SEED a whole number >= 0")
    return int(m.group(1) or 20_000), int(m.group(2) or 0)


@dataclass
class SceneSemantics:
    """What answers text on a cinesplat scene (latents + codec): its SemanticScene, label names and matcher."""

    semantic: Any  # method.semantic_scene.SemanticScene
    label_names: List[str]
    free_text: bool  # whether free text (not only label names) means anything to it (free_text)
    match: Callable[[str], Dict[str, Any]]  # text -> the resolve_match dict (point, description, mask, ...)


@dataclass
class LoadedScene:
    """A scene as every command loads it (load_scene): obstacles, the Gaussians as read, what answers text and where
    the training cameras were. Fields that do not apply to a kind stay None / empty."""

    scene: Optional[EllipsoidScene]  # the obstacles; None when loaded with planning=False (cinesplat-preview)
    locate: Optional[Callable[[str], Tuple[np.ndarray, str]]]  # text -> (point [3], description)
    kind: str  # "procedural" | "ply" | "checkpoint" (config.yml, run folder, .ckpt, compact .npz / .pt)
    source: str
    config_path: Optional[Path] = None  # the run's config.yml (ns-render needs it)
    start_region: Optional[Tuple[np.ndarray, np.ndarray]] = None  # where random starts are drawn
    checkpoint: Optional[Any] = None  # method.checkpoint.SplatCheckpoint of a checkpoint or compact export
    room: Optional[Any] = None  # planner.scene.procedural.ProceduralRoom of a procedural spec
    semantics: Optional[SceneSemantics] = None  # a cinesplat scene's text semantics
    camera_centres: Optional[np.ndarray] = None  # [F, 3] training cameras
    camera_poses: Optional[np.ndarray] = None  # [F, 3, 4] (the standalone viewer's opening view)
    notes: List[str] = field(default_factory=list)  # said before planning (e.g. the training cameras are missing)
    planning_region: Optional[Tuple[np.ndarray, np.ndarray]] = None  # the box a compact export stores
    params: Optional[SplatParams] = field(default=None, repr=False)  # the Gaussians when no checkpoint holds them

    @property
    def splat(self) -> SplatParams:
        """The Gaussians as read (drawn by the viewer, rendered by the preview): a checkpoint's, a .ply's, a
        procedural room's with its display colours (procedural_params, built on first use)."""
        if self.checkpoint is not None:
            return self.checkpoint.params
        if self.params is None and self.room is not None:
            self.params = procedural_params(self.room)
        return self.params


SCENE_KINDS = ("a config.yml, run folder, .ckpt, compact .npz/.pt, .ply or procedural[:N[:SEED]]")


def _load_procedural(spec: str, proc: Tuple[int, int], cfg: SceneConfig, device: str, planning: bool,
                     **_: Any) -> LoadedScene:
    """procedural[:N[:SEED]]: the generated test room; its object names answer text (ground truth)."""
    from cinenerf_ns.planner.scene.procedural import procedural_room

    n, seed = proc
    room = procedural_room(n, seed=seed)
    names = [o.name for o in room.objects]

    def locate(text: str):
        i = procedural_object(room, text)
        c = room.objects[i].center.astype(np.float64)
        return c, (f"'{text.strip()}' -> object '{names[i]}' (ground-truth name), centre "
                   f"({', '.join(f'{v:.3f}' for v in c)})")

    r = cfg.camera_radius
    across = float(np.min(np.asarray(room.free_hi, np.float64) - np.asarray(room.free_lo, np.float64)))
    if planning and 2 * r >= across:  # the start region (the free space shrunk by r) would be inverted
        raise InvalidInputError(f"the camera sphere (--camera-radius + --safety-margin = {r:.4g}) is too large for "
                                f"this scene: the procedural room's free space is {across:.3g} scene units across")
    scene = (EllipsoidScene.from_splat(room.means, room.quats, room.log_scales, room.opacity_logits, cfg).to(device)
             if planning else None)
    return LoadedScene(scene, locate, "procedural", spec, room=room, start_region=(room.free_lo + r, room.free_hi - r))


def _load_ply(path: Path, cfg: SceneConfig, device: str, planning: bool, **_: Any) -> LoadedScene:
    """A 3DGS .ply (planner.scene.ply): obstacles only, targets as points."""
    from cinenerf_ns.planner.scene.ply import read_splat_ply

    splat = read_splat_ply(path)
    scene = EllipsoidScene.from_params(splat, cfg).to(device) if planning else None
    return LoadedScene(scene, None, "ply", str(path), params=splat)


def _load_checkpoint(path: Path, cfg: SceneConfig, device: str, planning: bool, **semantic_kw: Any) -> LoadedScene:
    """A run (config.yml, its folder, a .ckpt) or a compact export (.npz / .pt), through the method's loader (no
    trainer is built): obstacles, the training cameras, and for cinesplat scenes the text semantics."""
    from cinenerf_ns.method.checkpoint import (
        _is_compact,  # noqa: WPS450 (one loader, two formats)
        load_compact,
        load_splat,
    )

    st = load_compact(path, device=device) if _is_compact(path) else load_splat(path, device=device)
    cfg_path = run_config_path(path)
    cams = scene_camera_centres(cfg_path, st.info)  # the run's training cameras, else what a compact export carries
    if not planning:
        return LoadedScene(None, None, "checkpoint", str(path), config_path=cfg_path, checkpoint=st,
                           camera_centres=cams)
    scene = EllipsoidScene.from_params(st.params, cfg, device=device)
    semantics = None
    if st.params.latents is not None and st.codec is not None:
        semantics = _semantics(st, cams, device, **semantic_kw)
    region = camera_box(cams) if cams is not None else None
    if region is None and st.info.get("start_region"):  # compact exports carry their training cameras' box
        lo, hi = (np.asarray(v, dtype=np.float64) for v in st.info["start_region"])
        region = (lo, hi)
    poses = scene_camera_poses(cfg_path, st.info)  # [F, 3, 4] or None (the viewer's opening view)
    notes = [] if cams is not None or cfg_path is None else [missing_cameras_note(cfg_path)]
    locate = None
    if semantics is not None:
        def locate(text: str):
            m = semantics.match(text)
            return m["point"], m["description"]

    return LoadedScene(scene, locate, "checkpoint", str(path), config_path=cfg_path, start_region=region,
                       checkpoint=st, semantics=semantics, camera_centres=cams, camera_poses=poses, notes=notes,
                       planning_region=stored_region(st.info, path))


def _semantics(st: Any, cams: Optional[np.ndarray], device: str, threshold: Optional[float] = None,
               smooth_neighbors: int = SMOOTH_NEIGHBORS, object_cluster: float = OBJECT_CLUSTER,
               object_centre: str = "volume", up: Tuple[float, float, float] = (0.0, 0.0, 1.0),
               drop_support: bool = True, centre_relevancy: float = CENTRE_RELEVANCY,
               unseen_fill: bool = True) -> SceneSemantics:
    """The text semantics of a cinesplat checkpoint (latents + codec): a SemanticScene and its matcher."""
    from cinenerf_ns.method.semantic_scene import SemanticScene, build_text_encoder

    enc = build_text_encoder(st.info, st.label_embeddings, device=device)
    kw = {} if threshold is None else {"threshold": threshold}
    sem = SemanticScene.from_params(st.params, st.codec, enc, device, label_names=st.info.get("label_names"),
                                    smooth_neighbors=smooth_neighbors, cluster_fraction=object_cluster,
                                    centre=object_centre, up=up, drop_support=drop_support,
                                    centre_relevancy=centre_relevancy,
                                    camera_centres=cams if unseen_fill else None, **kw)
    label_names = list(st.info.get("label_names") or [])
    free = free_text(st.info)

    def match(text: str) -> Dict[str, Any]:
        q = label_query(text, label_names, free)
        r = sem.locate_full(q)
        n, k = int(r.mask.sum()), int(r.core.sum())
        c = r.centroid.detach().cpu().numpy().astype(np.float64)
        best = float(r.relevancy.max())
        picked = "" if q == text.strip() else f" -> label '{q}'"
        core = "" if k == n else f", centre from the {k} above {sem.centre_relevancy:g}"
        desc = (f"'{text.strip()}'{picked}: {n} Gaussians above relevancy {sem.threshold:g} (best "
                f"{best:.3f}){core}, "
                f"centre ({', '.join(f'{v:.3f}' for v in c)})")
        return {"text": text.strip(), "query": q, "label": q if q in label_names else None, "gaussians": n,
                "core_gaussians": k, "best_relevancy": best, "centre": c.tolist(), "description": desc, "point": c,
                "mask": r.mask.detach().cpu().numpy().astype(bool)}

    return SceneSemantics(sem, label_names, free, match)


def _unknown_suffix(path: Path, *_: Any, **__: Any) -> LoadedScene:
    from cinenerf_ns.method.scene_files import SUPPORTED, CheckpointError

    raise CheckpointError(f"{path} is not a checkpoint or scene file this tool reads (suffix "
                          f"{path.suffix or 'none'!r}); give {SUPPORTED}")


# The one table of scene files: a path's suffix (lower case) -> its reader; any other folder is a run folder
# (checkpoint) and 'procedural[:N[:SEED]]' is no file. A new format is one reader here.
SCENE_READERS: Dict[str, Callable[..., LoadedScene]] = {
    ".ply": _load_ply,
    ".npz": _load_checkpoint, ".pt": _load_checkpoint, ".ckpt": _load_checkpoint,
    ".yml": _load_checkpoint, ".yaml": _load_checkpoint,
}


def load_scene(spec: str, cfg: Optional[SceneConfig] = None, device: str = "cpu", threshold: Optional[float] = None,
               smooth_neighbors: int = SMOOTH_NEIGHBORS, object_cluster: float = OBJECT_CLUSTER,
               object_centre: str = "volume",
               up: Tuple[float, float, float] = (0.0, 0.0, 1.0), drop_support: bool = True,
               centre_relevancy: float = CENTRE_RELEVANCY, unseen_fill: bool = True,
               planning: bool = True) -> LoadedScene:
    """The one scene loader of every command (cinesplat-plan, cinesplat-viewer, cinesplat-preview, the benchmarks):
    a scene file or spec (SCENE_KINDS) -> LoadedScene, through SCENE_READERS. ``planning`` False: the Gaussians
    only (no obstacles, no text semantics: what a renderer needs). InvalidInputError / CheckpointError name the
    file and the problem."""
    cfg = cfg or SceneConfig()
    proc = procedural_spec(spec)
    if proc is not None:
        return _load_procedural(spec, proc, cfg, device, planning)
    path = Path(spec)
    problem = path_problem(path, folder_ok=True)
    if problem == "was not found":
        raise InvalidInputError(f"scene not found: {spec} (give {SCENE_KINDS})")
    if problem is not None:
        raise InvalidInputError(f"scene {spec} {problem}")
    reader = SCENE_READERS.get(path.suffix.lower()) or (_load_checkpoint if path.is_dir() else _unknown_suffix)
    return reader(path, cfg, device, planning, threshold=threshold, smooth_neighbors=smooth_neighbors,
                  object_cluster=object_cluster, object_centre=object_centre, up=up, drop_support=drop_support,
                  centre_relevancy=centre_relevancy, unseen_fill=unseen_fill)


def missing_cameras_note(config_path: Path) -> str:
    """What a run planned without its training cameras loses, and why (its dataset moved or is unreadable)."""
    from cinenerf_ns.method.training_cameras import run_data_path

    data = run_data_path(config_path)
    why = ("its config names no dataset" if data is None else f"its dataset {data} is gone" if not data.exists()
           else f"its training cameras could not be read from {data}")
    return (f"{config_path}: {why}; planning without the training cameras (random starts anywhere in the scene's "
            f"free space, text targets' centres without the unseen-part fill)")


def stored_region(info: Dict[str, Any], path: Any) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    """The planning region a compact export stores (export_compact's planning_region) as (lo [3], hi [3]), or None;
    CheckpointError when it is there but not a valid box."""
    reg = info.get("planning_region")
    if reg is None:
        return None
    from cinenerf_ns.method.scene_files import CheckpointError
    from cinenerf_ns.planner.scene.user_box import user_box

    try:
        return user_box((reg["lo"], reg["hi"]), "the stored planning region")
    except (InvalidInputError, KeyError, TypeError) as e:
        raise CheckpointError(f"{path}: its stored planning region is not a valid box: {e}") from e


def resolve_match(text: str, loaded: LoadedScene, what: str) -> Dict[str, Any]:
    """A target's text -> {"point" [3], "description", and for text: "query", "label", "gaussians", "best_relevancy",
    "centre", "mask" (bool [N] over the splat's Gaussians: the object's, when the scene can tell)}.
    InvalidInputError for empty text, text on a scene without semantics, text that matches nothing."""
    if not isinstance(text, str) or not text.strip():
        raise InvalidInputError(f"the {what} target is empty: type an object (text) or a point 'x y z'")
    p = parse_point(text)
    if p is not None:
        if not np.all(np.isfinite(p)):
            raise InvalidInputError(f"the {what} point {text!r} is not finite: give three finite numbers 'x y z'")
        return {"text": text.strip(), "point": p, "description": f"point {np.round(p, 4).tolist()}"}
    if loaded.locate is None:
        raise InvalidInputError(
            f"'{text}' is text, but this scene ({loaded.kind}) has no semantics; give the {what} target as 'x y z' "
            f"or use a cinesplat checkpoint"
        )
    from cinenerf_ns.method.clip_features import ClipWeightsError

    try:
        if loaded.semantics is not None:
            return loaded.semantics.match(text)
        point, desc = loaded.locate(text)
    except ClipWeightsError as e:  # its own advice names ns-train options
        first = str(e).strip().splitlines()[0] if str(e).strip() else "the CLIP weights are missing"
        labels = loaded.semantics.label_names if loaded.semantics is not None else []
        names = f", or one of the scene's object names: {', '.join(labels)}" if labels else ""
        raise InvalidInputError(
            f"'{text.strip()}' needs the scene's CLIP text model, which cannot be loaded here ({first}); run once "
            f"with network so open_clip caches its weights, or give the {what} target as a point 'x y z'{names}"
        ) from None
    out = {"text": text.strip(), "point": point, "description": desc}
    if loaded.room is not None:  # a procedural room: the object's Gaussians from its ground truth
        room = loaded.room
        out["mask"] = room.object_ids.cpu().numpy() == procedural_object(room, text)
    return out


PROCEDURAL_COLOURS = np.array([[0.85, 0.25, 0.2], [0.2, 0.7, 0.3], [0.25, 0.4, 0.9], [0.9, 0.75, 0.2],
                               [0.7, 0.3, 0.8], [0.2, 0.75, 0.8], [0.95, 0.5, 0.2], [0.5, 0.5, 0.9]], np.float32)


def procedural_colours(room: Any) -> np.ndarray:
    """float32 [N, 3] display colours of a procedural room's Gaussians: objects in distinct colours, the rest grey."""
    ids = room.object_ids.cpu().numpy()
    return np.where(ids[:, None] >= 0, PROCEDURAL_COLOURS[np.maximum(ids, 0) % len(PROCEDURAL_COLOURS)],
                    np.float32(0.6)).astype(np.float32)


def procedural_params(room: Any) -> SplatParams:
    """The Gaussians of a procedural room (planner.procedural) with their display colours (procedural_colours)."""
    return SplatParams.of(room.means, room.quats, room.log_scales, room.opacity_logits,
                          colors_dc=rgb_to_dc(procedural_colours(room)))


def preview_scene(loaded: LoadedScene):
    """The renderable splat (cinenerf_ns.preview PreviewScene, SH degree 0) of a loaded scene: a checkpoint's or compact
    export's Gaussians, a .ply's (grey where it has no colour), a procedural room's (objects coloured, the rest
    grey)."""
    from cinenerf_ns.preview.render import scene_from_splat

    return scene_from_splat(loaded.splat, grey=NO_COLOUR_GREY if loaded.kind == "ply" else None)
