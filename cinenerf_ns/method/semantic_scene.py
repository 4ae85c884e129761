"""``SemanticScene``: text query -> per-Gaussian relevancy, object mask, centroid and extent.

One API for the planner, the CLI and the viewer. Pure torch + the codec; the text encoder is any callable
``list[str] -> [T, D]`` (``build_text_encoder`` makes the standard one from a checkpoint's info: the label
table first, then the open_clip text tower). No nerfstudio / gsplat import.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, Optional, Sequence, Tuple, Union

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from cinenerf_ns.method.relevancy import (
    CHUNK as RELEVANCY_CHUNK,
    DEFAULT_NEGATIVES,
    QueryError,
    centre_core,
    object_centroid_extent,
    relevancy as relevancy_fn,
    relevancy_mask,
)
from cinenerf_ns.method.scene_files import CheckpointError
from cinenerf_ns.planner.scene.splat_params import SplatParams
from cinenerf_ns.semantic_defaults import CENTRE_RELEVANCY

TextEncoder = Callable[[Sequence[str]], Tensor]


def build_text_encoder(info: Dict, label_embeddings: Optional[Tensor] = None,
                       device: torch.device | str = "cpu") -> TextEncoder:
    """Texts equal (case-insensitively) to a trained label name use that label's stored embedding (exact,
    needs no CLIP weights); other texts go through the CLIP text tower named in ``info["clip"]``,
    loaded on first use (raises ClipWeightsError with instructions when weights are missing). CheckpointError when the
    label names and embeddings disagree in number: the labels could not be answered, and their text would silently go
    to the CLIP tower (random weights on label-trained scenes)."""
    names = [n.strip().lower() for n in (info.get("label_names") or [])]
    n_emb = 0 if label_embeddings is None or label_embeddings.numel() == 0 else int(label_embeddings.shape[0])
    if n_emb != len(names):
        raise CheckpointError(
            f"the scene holds {len(names)} label names (info 'label_names') but {n_emb} label embeddings "
            f"('label_embeddings'): each label needs its embedding, so its text queries cannot be answered; the scene "
            f"file is inconsistent: export it again from its training run")
    table = {n: label_embeddings[i].float() for i, n in enumerate(names)}
    state: Dict = {}

    def encode(texts: Sequence[str]) -> Tensor:
        out: list = [None] * len(texts)
        missing = []
        for i, t in enumerate(texts):
            key = t.strip().lower()
            if key in table:
                out[i] = table[key].to(device)
            else:
                missing.append(i)
        if missing:
            if "enc" not in state:
                if not info.get("clip"):
                    raise QueryError(
                        "this scene has no text encoder spec; only its label names can be queried: "
                        + ", ".join(info.get("label_names") or [])
                    )
                from cinenerf_ns.method.clip_features import ClipWeightsError, clip_config_from_spec, make_text_encoder

                try:
                    state["enc"] = make_text_encoder(clip_config_from_spec(info["clip"]), device)
                except ClipWeightsError as e:
                    raise QueryError(_no_clip_advice(info, e.reason, [texts[i] for i in missing])) from None
            emb = state["enc"]([texts[i] for i in missing])
            for j, i in enumerate(missing):
                out[i] = emb[j].to(device)
        return F.normalize(torch.stack(out).float(), dim=-1)

    return encode


def _no_clip_advice(info: Dict, reason: str, texts: Sequence[str]) -> str:
    """What a user querying free text can do when the scene's CLIP text tower does not load (at query time: no
    training options apply)."""
    clip = info.get("clip") or {}
    if clip.get("checkpoint_path"):
        fix = f"put the CLIP checkpoint file back at {clip['checkpoint_path']} (where the scene was trained with it)"
    else:
        fix = (f"cache its weights once on a machine with network (python -c \"import open_clip; "
               f"open_clip.create_model('{clip.get('model_name')}', pretrained='{clip.get('pretrained')}')\")")
    names = info.get("label_names") or []
    labels = f"type one of the scene's label names ({', '.join(names)}) or " if names else ""
    quoted = ", ".join(f"'{t.strip()}'" for t in texts)
    return (f"free text ({quoted}) needs this scene's CLIP text tower, which cannot be loaded here: {reason}. For free "
            f"text, {fix}; otherwise {labels}give the target as a point 'x y z'")


def knn_indices(points: np.ndarray, k: int) -> np.ndarray:
    """Indices of each point's k nearest points (itself included), nearest first: scipy's exact cKDTree query, asked
    in the tree's leaf order (neighbouring queries walk the same nodes: half the CPU time on a splat whose Gaussians
    are stored in no spatial order) and put back in the points' order. points [N, 3] -> [N, k] int64."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    order = tree.indices  # [N] the points in leaf order
    _, idx_in_order = tree.query(points[order], k=k, workers=-1)  # [N, k]
    idx = np.empty_like(idx_in_order)
    idx[order] = idx_in_order
    return idx


def smooth_latents(means: Tensor, opacities: Tensor, latents: Tensor, k: int) -> Tensor:
    """Opacity-weighted mean of each Gaussian's latent over its k nearest Gaussians (itself included).

    Why: distillation supervises only the alpha-blend of many Gaussians per feature pixel, so single
    Gaussians' latents are noisy although the rendered latent image is right; averaging over spatial
    neighbours is closer to what the renderer shows (measured on the synthetic room: IoU of the large
    objects 0.46-0.60 -> 0.65-0.81 at k=32). An approximation: it blurs across object borders by up
    to the k-neighbourhood's radius. KD-tree on the CPU (scipy): seconds for a few 100k Gaussians.
    means [N, 3], opacities [N], latents [N, C] -> [N, C] (same device / dtype as latents)."""
    n = means.shape[0]
    k = min(int(k), n)
    if k <= 1:
        return latents
    idx = knn_indices(means.detach().float().cpu().numpy(), k)  # [N, k]
    idx_t = torch.from_numpy(idx).to(latents.device)
    w = opacities.detach().to(latents.device, latents.dtype).reshape(-1)[idx_t].clamp_min(1e-6)  # [N, k]
    return (latents.detach()[idx_t] * w[..., None]).sum(1) / w.sum(1, keepdim=True)


def dominant_cluster(means: Tensor, mask: Tensor, weights: Tensor, voxel: float) -> Tensor:
    """The part of ``mask`` that forms the heaviest spatial cluster: selected Gaussians are binned in voxels of
    size ``voxel``, 26-connected occupied voxels form clusters, and the cluster with the largest summed
    ``weights`` (e.g. relevancy x opacity) is kept. Why: a text query's selection also holds scattered false
    positives (and several instances of "a chair"); its centroid can then lie in empty space, while the
    camera needs one object. means [N, 3], mask [N] bool, weights [N] -> mask [N] bool (a subset of mask)."""
    from scipy import ndimage

    idx = torch.nonzero(mask).reshape(-1)
    if idx.numel() <= 1:
        return mask
    p = means[idx].detach().double().cpu().numpy()  # [K, 3]
    ijk = np.floor((p - p.min(0)) / float(voxel)).astype(np.int64)
    occ = np.zeros(tuple(ijk.max(0) + 1), dtype=bool)
    occ[tuple(ijk.T)] = True
    lab, n = ndimage.label(occ, structure=np.ones((3, 3, 3), dtype=bool))
    cl = lab[tuple(ijk.T)]  # [K] cluster id (>= 1) of each selected Gaussian
    mass = np.bincount(cl, weights=weights[idx].detach().double().cpu().numpy(), minlength=n + 1)
    mass[0] = -np.inf
    keep = torch.from_numpy(cl == int(np.argmax(mass))).to(mask.device)
    out = torch.zeros_like(mask)
    out[idx[keep]] = True
    return out


@dataclass
class LocateResult:
    # [3] the object's centre: the estimated volume centroid, or the surface one (SemanticScene.centre)
    centroid: Tensor
    mask: Tensor  # [N] bool
    lo: Tensor  # [3] axis-aligned extent of the masked means
    hi: Tensor  # [3]
    relevancy: Tensor  # [N]
    surface_centroid: Optional[Tensor] = None  # [3] opacity-weighted mean of the core's Gaussians
    core: Optional[Tensor] = None  # [N] bool, the part of mask the centre was estimated from (relevancy.centre_core)


CENTRES = ("volume", "surface")
# Text queries answered from memory per scene (SemanticScene.locate_full): enough for every label of a scene and the
# free-text queries of a session; each entry holds two [N] tensors (relevancy float, mask bool: ~2 MB at 400k).
LOCATE_CACHE_SIZE = 64


def normalise_text(text: str) -> str:
    """The cache key of a query's text: whitespace collapsed, case folded. Both text encoders treat such texts alike
    (build_text_encoder's label table compares case-insensitively; open_clip's tokenizer lower-cases and cleans
    whitespace), and so does the label contrast in SemanticScene._embed."""
    return " ".join(str(text).split()).lower()


class SemanticScene:
    """Gaussians (means, activated opacities, latents) + frozen codec + text encoder.

    means [N, 3], opacities [N] in [0, 1] (pass ``torch.sigmoid(logits)``), latents [N, 3]; optional
    log_scales [N, 3] (log sigmas, nerfstudio's ``scales``) and quats [N, 4] wxyz let the volume centre
    voxelise each Gaussian's extent instead of its mean alone.
    """

    def __init__(
        self,
        means: Tensor,
        opacities: Tensor,
        latents: Tensor,
        codec,
        text_encoder: TextEncoder,
        negatives: Sequence[str] = DEFAULT_NEGATIVES,
        temperature: float = 10.0,
        threshold: float = 0.5,
        min_opacity: float = 0.0,
        label_names: Optional[Sequence[str]] = None,
        smooth_neighbors: int = 0,
        cluster_fraction: float = 0.0,
        log_scales: Optional[Tensor] = None,
        quats: Optional[Tensor] = None,
        centre: str = "volume",
        up: Sequence[float] = (0.0, 0.0, 1.0),
        drop_support: bool = True,
        centre_relevancy: float = CENTRE_RELEVANCY,
        camera_centres: Optional[Union[Tensor, np.ndarray]] = None,
    ):
        """label_names: the scene's own label vocabulary (label-mask training). A query equal to one of
        them is contrasted against the *other* labels instead of ``negatives``: "floor lamp" must beat
        "floor", "wall", ... (the generic negatives only say "is it an object at all"), which is what
        separates objects whose embeddings are close.
        centre: what ``locate`` returns as the object's position: "volume" (estimated volume centroid, see
        object_centre.py; default) or "surface" (opacity-weighted mean of the selected Gaussians, which sit on
        surfaces: off the middle of objects with thin parts). up: world up (the volume estimate's vertical).
        drop_support: drop the floor / table layer under the selected object from the selection (features bleed
        across contact; see object_support.py).
        centre_relevancy: the centre (either kind) is estimated from the selected Gaussians with relevancy above this
        (the confident core, relevancy.centre_core; the whole selection when the core is under a quarter of it or
        under 4 Gaussians). The selection itself (mask, extent) keeps ``threshold``. At or below the selection
        threshold the rule is off.
        camera_centres: [C, 3] the training cameras' centres (the means' coordinates). The volume centre then also
        fills the part of the object that no training camera sees (object_centre.hidden_voxels: the unseen backs
        that a capture leaves thin); None: the ray vote alone."""
        n = means.shape[0]
        if means.shape != (n, 3) or latents.shape[0] != n or opacities.reshape(-1).shape[0] != n:
            raise ValueError(
                f"SemanticScene: inconsistent shapes means {tuple(means.shape)}, opacities {tuple(opacities.shape)}, "
                f"latents {tuple(latents.shape)}"
            )
        if centre not in CENTRES:
            raise ValueError(f"SemanticScene: centre must be one of {CENTRES}, got {centre!r}")
        try:
            cr = float(centre_relevancy)
        except (TypeError, ValueError):
            cr = float("nan")
        if not 0.0 <= cr < 1.0:
            raise ValueError(
                f"SemanticScene: centre_relevancy must be a number in [0, 1) (relevancies lie in (0, 1); "
                f"at or below the selection threshold the confident-core rule is off), got {centre_relevancy!r}"
            )
        for nm, t, d in (("log_scales", log_scales, 3), ("quats", quats, 4)):
            if t is not None and tuple(t.shape) != (n, d):
                raise ValueError(f"SemanticScene: {nm} must be [{n}, {d}], got {tuple(t.shape)}")
        cams = None
        if camera_centres is not None:
            cams = np.asarray(camera_centres.detach().cpu() if isinstance(camera_centres, Tensor) else camera_centres,
                              dtype=np.float64).reshape(-1, 3)
            if not np.isfinite(cams).all():
                raise ValueError("SemanticScene: camera_centres contain NaN/inf")
            cams = cams if len(cams) else None
        self.camera_centres: Optional[np.ndarray] = cams  # [C, 3] float64
        self.means = means
        self.log_scales = log_scales
        self.quats = quats
        self.centre = centre
        self.up = tuple(float(u) for u in up)
        self.drop_support = bool(drop_support)
        self.centre_relevancy = cr
        self.opacities = opacities.reshape(-1)
        self._raw_latents = latents
        self._smoothed: Optional[Tensor] = None
        self._sq_norms: Optional[Tuple[Tensor, Optional[Tensor]]] = None  # (latents, codec.decoded_sq_norms of them)
        self.smooth_neighbors = int(smooth_neighbors or 0)
        self.codec = codec
        self.text_encoder = text_encoder
        self.negatives = tuple(negatives)
        self.temperature = float(temperature)
        self.threshold = float(threshold)
        self.min_opacity = float(min_opacity)
        self.cluster_fraction = float(cluster_fraction or 0.0)
        self._robust_extent: Optional[float] = None
        self._neg_emb: Optional[Tensor] = None
        self.label_names = [str(x) for x in (label_names or [])]
        self._label_neg: Dict[str, Tensor] = {}
        self.cache_size = LOCATE_CACHE_SIZE
        self._cache: "OrderedDict[tuple, LocateResult]" = OrderedDict()  # LRU of locate_full, see _cache_key
        self._cache_lock = threading.Lock()  # guards _cache (short: lookups never wait for a computation)
        self._compute_lock = threading.RLock()  # one computation at a time (warm() on a thread + a viewer query)

    @classmethod
    def from_params(cls, params: SplatParams, codec, text_encoder: TextEncoder, device: torch.device | str = "cpu",
                    **kwargs) -> "SemanticScene":
        """Of a splat's parameters (with latents): its means, opacities, latents, log-scales and rotations as tensors
        on ``device``; ``kwargs`` as the constructor's."""
        if params.latents is None:
            raise QueryError("the splat has no semantic latents (a splatfacto scene?); "
                             "train it with ns-train cinesplat")
        means, quats, log_scales, logits = params.tensors(device)
        kwargs.setdefault("log_scales", log_scales)
        kwargs.setdefault("quats", quats)
        latents = torch.as_tensor(params.latents, device=device)
        return cls(means, torch.sigmoid(logits), latents, codec, text_encoder, **kwargs)

    @classmethod
    def from_checkpoint(cls, path: str | Path, device: torch.device | str = "cpu", **kwargs) -> "SemanticScene":
        """From a cinesplat config.yml / run folder / .ckpt / compact export (see checkpoint.py); the training cameras
        (``camera_centres``) from the run's dataset or the export's info unless given."""
        from cinenerf_ns.method.checkpoint import load_splat

        st = load_splat(path, device=device)
        if st.params.latents is None or st.codec is None:
            raise QueryError(f"{path} has no semantic latents (a splatfacto checkpoint?); "
                             "train it with ns-train cinesplat")
        enc = build_text_encoder(st.info, st.label_embeddings, device=device)
        kwargs.setdefault("label_names", st.info.get("label_names"))
        if "camera_centres" not in kwargs:  # the run's training cameras, else what a compact export carries
            from cinenerf_ns.method.training_cameras import run_config_path, scene_camera_centres

            kwargs["camera_centres"] = scene_camera_centres(run_config_path(Path(path)), st.info)
        return cls.from_params(st.params, st.codec, enc, device, **kwargs)

    @property
    def latents(self) -> Tensor:
        """[N, C] the latents queries use: smoothed over ``smooth_neighbors`` on first use (not at load: a
        scene may never be queried by text), else as given."""
        if self.smooth_neighbors <= 1:
            return self._raw_latents
        if self._smoothed is None:
            with self._compute_lock:  # a query during warm() waits for its smoothing instead of doing it twice
                if self._smoothed is None:
                    self._smoothed = smooth_latents(self.means, self.opacities, self._raw_latents,
                                                    self.smooth_neighbors)
        return self._smoothed

    def warm(self, labels: bool = True, negatives: bool = False,
             stop: Optional[threading.Event] = None) -> Dict[str, float]:
        """Compute what does not depend on a query's text now, off the request path (the standalone viewer calls this on
        a background thread after loading; the CLI, which asks one or two queries, leaves it lazy): the latent
        smoothing, the decoded norms every relevancy divides by, the scene's robust extent, and with ``labels`` the
        answer of every label name of the scene at the default threshold (a label fully determines it: same embedding,
        same contrast against the other labels), up to the cache's size; with ``negatives`` the generic negatives'
        embedding (may load the CLIP text tower; a failure is left for the first free-text query to report). Safe to
        call while queries run (they wait for the one computation in progress, then find their answer cached). Returns
        the seconds each part took.
        stop: set it to end the warm-up early (a viewer shutting down): checked before each part and between labels,
        so the warm-up returns within one part's time (a part is never interrupted; what is done stays cached); the
        result then has "stopped": 1.0 and no entry for the parts not run."""
        import time

        out: Dict[str, float] = {}

        def stopped() -> bool:
            if stop is not None and stop.is_set():
                out["stopped"] = 1.0
                return True
            return False

        if stopped():
            return out
        t0 = time.perf_counter()
        _ = self.latents
        out["smooth_s"] = time.perf_counter() - t0
        if stopped():
            return out
        t0 = time.perf_counter()
        self._decoded_sq_norms()
        out["norms_s"] = time.perf_counter() - t0
        if stopped():
            return out
        t0 = time.perf_counter()
        self._extent()
        out["extent_s"] = time.perf_counter() - t0
        if stopped():
            return out
        if negatives and self._neg_emb is None:
            t0 = time.perf_counter()
            try:
                with self._compute_lock:
                    if self._neg_emb is None:
                        self._neg_emb = self.text_encoder(list(self.negatives)).to(self._raw_latents.device)
            except Exception:  # noqa: BLE001 - e.g. missing CLIP weights: the query that needs them says so
                pass
            out["negatives_s"] = time.perf_counter() - t0
        if labels:
            t0 = time.perf_counter()
            for name in self.label_names[: self.cache_size]:
                if stopped():
                    return out
                try:
                    self.locate_full(name)
                except QueryError:  # a label nothing in the scene carries: the query itself will say so
                    pass
            out["labels_s"] = time.perf_counter() - t0
        return out

    def _cache_key(self, text: str, threshold: Optional[float]) -> tuple:
        """(normalised text, threshold used, the settings the answer depends on): a settings change is a new entry."""
        thr = self.threshold if threshold is None else float(threshold)
        return (normalise_text(text), thr, self.centre, self.centre_relevancy, self.drop_support, self.cluster_fraction,
                self.min_opacity, self.temperature, self.up, self.smooth_neighbors)

    def cache_clear(self) -> None:
        with self._cache_lock:
            self._cache.clear()

    def __len__(self) -> int:
        return self.means.shape[0]

    def _embed(self, text: str) -> Tuple[Tensor, Tensor]:
        if not isinstance(text, str) or not text.strip():
            raise QueryError("empty text query: type what the camera should look at, e.g. 'the red chair'")
        dev = self._raw_latents.device
        q = self.text_encoder([text.strip()])[0].to(dev)
        key = text.strip().lower()
        others = [n for n in self.label_names if n.strip().lower() != key]
        if others and len(others) < len(self.label_names):  # the query is one of the scene's labels
            if key not in self._label_neg:  # stored label embeddings: no CLIP text tower needed
                self._label_neg[key] = self.text_encoder(others).to(dev)
            return q, self._label_neg[key]
        if self._neg_emb is None:  # generic negatives: lazily, they may need the CLIP text tower
            self._neg_emb = self.text_encoder(list(self.negatives)).to(dev)
        return q, self._neg_emb

    @torch.no_grad()
    def query(self, text: str) -> Tensor:
        """Relevancy [N] in (0, 1) of every Gaussian for the text (eq. 4)."""
        q, neg = self._embed(text)
        return relevancy_fn(self.latents, self.codec, q, neg, temperature=self.temperature, chunk=RELEVANCY_CHUNK,
                            sq_norms=self._decoded_sq_norms())

    @torch.no_grad()
    def _decoded_sq_norms(self) -> Optional[Tensor]:
        """The codec's decoded_sq_norms of the query latents [N] (None when the codec has none), computed once: half
        of a relevancy's work that does not depend on the text. Chunked as relevancy chunks, so it rounds alike."""
        lat = self.latents
        if self._sq_norms is None or self._sq_norms[0] is not lat:
            with self._compute_lock:
                if self._sq_norms is None or self._sq_norms[0] is not lat:
                    norms = None
                    if hasattr(self.codec, "decoded_sq_norms"):
                        parts = [self.codec.decoded_sq_norms(lat[i : i + RELEVANCY_CHUNK])
                                 for i in range(0, lat.shape[0], RELEVANCY_CHUNK)]
                        norms = None if not parts or parts[0] is None else torch.cat(parts)
                    self._sq_norms = (lat, norms)
        return self._sq_norms[1]

    @torch.no_grad()
    def locate_full(self, text: str, threshold: Optional[float] = None) -> LocateResult:
        """The selection, extent and centre of the text's object (see locate). Answers are kept in an LRU of
        ``cache_size`` entries keyed by (normalised text, threshold, settings): a repeated query returns the same
        LocateResult object without encoding the text or computing relevancy (treat its tensors as read-only).
        Queries that match nothing raise QueryError each time (not cached)."""
        if not isinstance(text, str) or not text.strip():
            raise QueryError("empty text query: type what the camera should look at, e.g. 'the red chair'")
        key = self._cache_key(text, threshold)
        hit = self._cached(key)
        if hit is not None:
            return hit
        with self._compute_lock:
            hit = self._cached(key)  # computed by another thread (warm()) while this one waited
            if hit is not None:
                return hit
            res = self._locate_uncached(text, threshold)
            with self._cache_lock:
                self._cache[key] = res
                while len(self._cache) > max(int(self.cache_size), 0):
                    self._cache.popitem(last=False)
            return res

    def _cached(self, key: tuple) -> Optional[LocateResult]:
        with self._cache_lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
            return hit

    def _locate_uncached(self, text: str, threshold: Optional[float] = None) -> LocateResult:
        rel = self.query(text)
        thr = self.threshold if threshold is None else float(threshold)
        mask = relevancy_mask(rel, thr, self.opacities, self.min_opacity)
        if not bool(mask.any()):
            best = float(rel.max()) if rel.numel() else float("nan")
            raise QueryError(
                f"nothing in the scene matches '{text.strip()}': highest relevancy {best:.3f} is below the threshold "
                f"{thr:.2f} (try other words or a lower threshold)"
            )
        if self.cluster_fraction > 0:
            mask = dominant_cluster(self.means, mask, rel * self.opacities, self._voxel())
        if self.drop_support:
            from cinenerf_ns.method.object_support import drop_support_layer

            # the ring around the footprint: 1/2 to 3/2 of the clustering voxel (2% of the scene's extent by default)
            v = self._voxel() if self.cluster_fraction > 0 else self._extent() * 0.02
            mask = drop_support_layer(self.means, mask, up=self.up, inner=0.5 * v, outer=1.5 * v)
        _, lo, hi = object_centroid_extent(self.means, self.opacities, mask)  # the extent: the whole selection
        core = centre_core(rel, mask, self.centre_relevancy, thr)  # the centre: its confident core
        c, _, _ = object_centroid_extent(self.means, self.opacities, core)
        centre = c if self.centre == "surface" else self.volume_centre(core)
        return LocateResult(centroid=centre, mask=mask, lo=lo, hi=hi, relevancy=rel, surface_centroid=c, core=core)

    def volume_centre(self, mask: Tensor) -> Tensor:
        """Estimated volume centroid [3] (means' dtype and device) of the Gaussians in ``mask`` [N] bool."""
        from cinenerf_ns.method.object_centre import volume_centroid

        sc = None if self.log_scales is None else torch.exp(self.log_scales[mask].detach().double())
        q = None if self.quats is None else self.quats[mask].detach()
        c = volume_centroid(self.means[mask], sc, q, up=self.up, cameras=self.camera_centres)
        return torch.as_tensor(c, dtype=self.means.dtype, device=self.means.device)

    def _voxel(self) -> float:
        """cluster_fraction x the scene's robust extent."""
        return max(self._extent() * self.cluster_fraction, 1e-9)

    def _extent(self) -> float:
        """The scene's robust extent: longest side of the 1%-99% quantile box of the means."""
        if self._robust_extent is None:
            m = self.means.detach().float()
            if m.shape[0] > 200_000:  # quantiles of a subsample: the extent does not need every point
                m = m[torch.randperm(m.shape[0], generator=torch.Generator().manual_seed(0))[:200_000].to(m.device)]
            q = torch.quantile(m, torch.tensor([0.01, 0.99], device=m.device), dim=0)
            self._robust_extent = max(float((q[1] - q[0]).max()), 1e-9)
        return self._robust_extent

    def locate(self, text: str, threshold: Optional[float] = None) -> Tuple[Tensor, Tensor]:
        """(object centre [3] (see ``centre``), mask [N] bool) of the Gaussians above the relevancy threshold."""
        r = self.locate_full(text, threshold)
        return r.centroid, r.mask
