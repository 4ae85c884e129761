"""Malformed scene files: load_scene raises InvalidInputError or CheckpointError naming the file and the problem
(never a traceback of another type, numpy's allow_pickle or torch's weights_only advice, a bare int() error)."""
from __future__ import annotations

import io
import json
import re
import sys
import time
import tracemalloc
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from cinenerf_ns.method.checkpoint import CheckpointError, SplatCheckpoint, export_compact
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.ply import write_splat_ply
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.scene.splat_params import SplatParams
from cinenerf_ns.scenes import load_scene

REPO = Path(__file__).resolve().parents[1]
FOX_NPZ = REPO.parent / "shared" / "data" / "fox_cinesplat" / "fox3000.npz"
SPLAT_PROPS = ("x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "opacity")
ADVICE = re.compile(r"allow_pickle|weights_only|Traceback|invalid literal for int", re.IGNORECASE)


@pytest.fixture(autouse=True)
def no_models(monkeypatch):
    """A malformed file must fail before any text encoder (CLIP) or semantic scene is built."""
    import cinenerf_ns.method.semantic_scene as ss

    def boom(*a, **k):
        raise AssertionError("the semantic stage was reached before the file was validated")

    monkeypatch.setattr(ss, "build_text_encoder", boom)
    monkeypatch.setattr(ss, "SemanticScene", boom)


def fails(spec, exc, problem: str, names: str | None = None) -> str:
    """load_scene(spec) raises exactly ``exc`` whose message names the file (or ``names``) and matches ``problem``."""
    with pytest.raises(Exception) as ei:
        load_scene(str(spec), SceneConfig())
    e = ei.value
    msg = str(e)
    assert isinstance(e, exc), f"{type(e).__name__}: {msg}"
    assert (names or str(spec)) in msg, msg
    assert re.search(problem, msg), msg
    assert not ADVICE.search(msg), msg
    return msg


# ------------------------------------------------------------------------------------------- helpers
def tiny_splat(n: int = 6, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    return {"means": torch.randn(n, 3, generator=g), "quats": torch.randn(n, 4, generator=g),
            "scales": torch.randn(n, 3, generator=g) - 3, "opacities": torch.randn(n, generator=g) + 2}


def save_npz(path: Path, info: object = "{}", **arrays) -> Path:
    flat = {k: (v.numpy() if isinstance(v, torch.Tensor) else v) for k, v in arrays.items()}
    if info is not None:
        flat["info_json"] = np.array(info)
    with open(path, "wb") as f:
        np.savez(f, **flat)
    return path


def write_ply(path: Path, props=SPLAT_PROPS, count: str | int = 2, rows=None, fmt="binary_little_endian",
              end_header: bool = True) -> Path:
    head = f"ply\nformat {fmt} 1.0\nelement vertex {count}\n" + "".join(f"property float {p}\n" for p in props)
    head += "end_header\n" if end_header else ""
    if rows is None:
        rows = np.ones((int(count) if str(count).isdigit() else 0, len(props)), np.float32)
    if fmt == "ascii":
        body = "".join(" ".join(map(str, r)) + "\n" for r in rows).encode()
    else:
        body = np.asarray(rows, "<f4").tobytes()
    path.write_bytes(head.encode() + body)
    return path


# ------------------------------------------------------------------------------------------- .npz
def test_npz_empty_and_not_a_zip(tmp_path):
    (tmp_path / "e.npz").write_bytes(b"")
    fails(tmp_path / "e.npz", CheckpointError, r"is empty \(0 bytes\)")
    (tmp_path / "r.npz").write_bytes(np.random.default_rng(0).bytes(3000))
    fails(tmp_path / "r.npz", CheckpointError, r"not a \.npz archive")


def test_npz_no_arrays_and_missing_entries(tmp_path):
    with open(tmp_path / "none.npz", "wb") as f:
        np.savez(f)
    fails(tmp_path / "none.npz", CheckpointError, r"holds no arrays: not a cinesplat compact export")
    s = tiny_splat()
    no_means = {k: v for k, v in s.items() if k != "means"}
    fails(save_npz(tmp_path / "nm.npz", **no_means), CheckpointError, r"has no means: not a cinesplat compact")
    fails(save_npz(tmp_path / "ni.npz", info=None, **s), CheckpointError, r"has no info_json")
    fails(save_npz(tmp_path / "bad.npz", info="{not json", **s), CheckpointError, r"info_json is not valid JSON")
    fails(save_npz(tmp_path / "lst.npz", info="[1, 2]", **s), CheckpointError, r"info_json must be a JSON object")
    fails(save_npz(tmp_path / "sr.npz", info='{"start_region": [1, 2]}', **s), CheckpointError, r"start_region")
    fails(save_npz(tmp_path / "num.npz", info=np.float32(3), **s), CheckpointError, r"info_json must be one text")
    codec = json.dumps({"feature_dim": 24, "codec_config": {"no_such_option": 1}})
    fails(save_npz(tmp_path / "codec.npz", info=codec, **s, **{"codec.w": np.zeros(3)}), CheckpointError,
          r"feature codec cannot be rebuilt .*TypeError")


def test_npz_object_arrays_are_not_unpickled(tmp_path):
    p = tmp_path / "obj.npz"
    with open(p, "wb") as f:
        np.savez(f, means=np.array([{"a": 1}, None], dtype=object), info_json=np.array("{}"))
    fails(p, CheckpointError, r"array 'means' holds pickled Python objects: not a cinesplat compact export")


def test_npz_shapes_and_lengths(tmp_path):
    s = tiny_splat(5)
    fails(save_npz(tmp_path / "m2.npz", **{**s, "means": torch.zeros(5, 2)}), CheckpointError,
          r"means must be \[N, 3\].*\(5, 2\)")
    fails(save_npz(tmp_path / "len.npz", **{**s, "opacities": torch.zeros(4)}), CheckpointError,
          r"opacities has 4 rows but means has 5")
    fails(save_npz(tmp_path / "q3.npz", **{**s, "quats": torch.zeros(5, 3)}), CheckpointError,
          r"quats must be \[N, 4\], got \(5, 3\)")
    fails(save_npz(tmp_path / "zero.npz", **{k: v[:0] for k, v in s.items()}), CheckpointError,
          r"holds 0 Gaussians")
    fails(save_npz(tmp_path / "bool.npz", **{**s, "scales": np.zeros((5, 3), bool)}), CheckpointError,
          r"'scales' holds bool values, not numbers")


def test_npz_non_finite(tmp_path):
    s = tiny_splat(6)
    means = s["means"].clone()
    means[0, 0], means[3, 2] = float("nan"), float("inf")
    with pytest.warns(UserWarning, match="dropped 2 Gaussians with NaN/inf"):
        ld = load_scene(str(save_npz(tmp_path / "some.npz", **{**s, "means": means})), SceneConfig())
    assert len(ld.scene) == 4
    fails(save_npz(tmp_path / "all.npz", **{**s, "means": torch.full((6, 3), float("nan"))}), CheckpointError,
          r"no usable Gaussians: all 6 have NaN/inf")


def test_npz_truncated_export(tmp_path):
    s = tiny_splat(200)
    st = SplatCheckpoint(SplatParams.of(s["means"], s["quats"], s["scales"], s["opacities"],
                                        colors_dc=torch.randn(200, 3)),
                         info={"label_names": ["a"]})
    p = export_compact(st, tmp_path / "scene.npz")
    assert len(load_scene(str(p), SceneConfig()).scene) > 0  # the export itself loads
    half = tmp_path / "half.npz"
    half.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    fails(half, CheckpointError, r"truncated or corrupt")


def test_npz_huge_claimed_shape_is_not_allocated(tmp_path):
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f4", "fortran_order": False, "shape": (10**12, 3)})
    p = tmp_path / "huge.npz"
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("means.npy", buf.getvalue() + b"\0" * 64)
    tracemalloc.start()
    try:
        fails(p, CheckpointError, r"truncated or corrupt: array 'means' claims shape \(1000000000000, 3\)")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50e6


# ------------------------------------------------------------------------------------------- .pt / .ckpt
@pytest.mark.parametrize("suffix", [".pt", ".ckpt"])
def test_torch_files_empty_random_and_unsafe(tmp_path, suffix):
    (tmp_path / f"e{suffix}").write_bytes(b"")
    fails(tmp_path / f"e{suffix}", CheckpointError, r"is empty \(0 bytes\)")
    (tmp_path / f"r{suffix}").write_bytes(b"hello" + np.random.default_rng(1).bytes(2000))
    fails(tmp_path / f"r{suffix}", CheckpointError, r"is not a PyTorch file")
    (tmp_path / f"p{suffix}").write_bytes(b"\x80" + np.random.default_rng(2).bytes(2000))  # looks like a pickle
    fails(tmp_path / f"p{suffix}", CheckpointError, r"truncated or corrupt|holds Python objects")
    torch.save({"x": SceneConfig()}, tmp_path / f"o{suffix}")  # a pickled class: never unpickled
    fails(tmp_path / f"o{suffix}", CheckpointError, r"holds Python objects other than tensors")
    good = tmp_path / f"g{suffix}"
    torch.save({"format": "cinesplat-compact", "arrays": tiny_splat(), "codec": {}, "info_json": "{}"}, good)
    good.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    fails(good, CheckpointError, r"truncated or corrupt")


def test_pt_wrong_contents(tmp_path):
    torch.save([1, 2, 3], tmp_path / "list.pt")
    fails(tmp_path / "list.pt", CheckpointError, r"holds a list: not a cinesplat compact export")
    torch.save({"weights": torch.zeros(3)}, tmp_path / "dict.pt")
    fails(tmp_path / "dict.pt", CheckpointError, r"not a cinesplat compact export \(no format 'cinesplat-compact'")
    s = tiny_splat()
    del s["quats"]
    torch.save({"format": "cinesplat-compact", "arrays": s, "codec": {}, "info_json": "{}"}, tmp_path / "nq.pt")
    fails(tmp_path / "nq.pt", CheckpointError, r"has no quats array")
    torch.save({"format": "cinesplat-compact", "arrays": tiny_splat(), "codec": {}}, tmp_path / "ni.pt")
    fails(tmp_path / "ni.pt", CheckpointError, r"has no info_json")
    torch.save({"format": "cinesplat-compact", "arrays": [1], "codec": {}, "info_json": "{}"}, tmp_path / "al.pt")
    fails(tmp_path / "al.pt", CheckpointError, r"'arrays' must be a dict of tensors")


def test_ckpt_wrong_contents(tmp_path):
    torch.save({"step": 3, "optimizers": {}}, tmp_path / "x.ckpt")
    fails(tmp_path / "x.ckpt", CheckpointError, r"not a splatfacto/cinesplat checkpoint")
    torch.save([torch.zeros(2)], tmp_path / "l.ckpt")
    fails(tmp_path / "l.ckpt", CheckpointError, r"not a splatfacto/cinesplat checkpoint.*holds a list")
    sd = {"_model.gauss_params." + k: v for k, v in tiny_splat(5).items()}
    sd["_model.gauss_params.quats"] = torch.zeros(5, 3)
    torch.save({"pipeline": sd}, tmp_path / "q.ckpt")
    fails(tmp_path / "q.ckpt", CheckpointError, r"quats must be \[N, 4\]")
    del sd["_model.gauss_params.quats"]
    torch.save({"pipeline": sd}, tmp_path / "nq.ckpt")
    fails(tmp_path / "nq.ckpt", CheckpointError,
          r"has no quats tensor \(a splat needs means, quats, scales, opacities\)")


# ------------------------------------------------------------------------------------------- config.yml / folders
def test_config_yml(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "config.yml").write_text("")
    fails(tmp_path / "a" / "config.yml", CheckpointError, r"is empty \(0 bytes\)")
    (tmp_path / "a" / "config.yml").write_text("method_name: [cinesplat\nmax: {: :\n")
    fails(tmp_path / "a" / "config.yml", CheckpointError, r"is not valid YAML .*line \d+, column \d+")
    fails(tmp_path / "a", CheckpointError, r"is not valid YAML", names=str(tmp_path / "a" / "config.yml"))
    (tmp_path / "a" / "config.yml").write_text("just a sentence\n")
    fails(tmp_path / "a" / "config.yml", CheckpointError, r"not a nerfstudio config.yml")
    (tmp_path / "a" / "config.yml").write_text("!!python/object:nerfstudio.engine.trainer.TrainerConfig\n"
                                               "method_name: cinesplat\n")
    fails(tmp_path / "a" / "config.yml", CheckpointError, r"no checkpoint found for .*config.yml: no \.ckpt in "
          + re.escape(str(tmp_path / "a" / "nerfstudio_models")))


def test_folders_and_unknown_suffix(tmp_path):
    (tmp_path / "empty").mkdir()
    fails(tmp_path / "empty", CheckpointError,
          r"is a folder with no config.yml and no \.ckpt in .*config.yml.*run folder.*\.ckpt.*\.npz.*\.pt.*\.ply"
          r".*procedural\[:N\[:SEED\]\]")
    (tmp_path / "run" / "nerfstudio_models").mkdir(parents=True)
    fails(tmp_path / "run", CheckpointError, r"no checkpoint found in .*nerfstudio_models.* and no config.yml")
    (tmp_path / "notes.txt").write_text("hello")
    fails(tmp_path / "notes.txt", CheckpointError,
          r"suffix '\.txt'.*config.yml.*run folder.*\.ckpt.*\.npz.*\.pt.*\.ply.*procedural\[:N\[:SEED\]\]")
    fails(tmp_path / "missing.npz", InvalidInputError, r"scene not found.*\.npz/\.pt.*procedural\[:N\[:SEED\]\]")


# ------------------------------------------------------------------------------------------- .ply
def test_ply_header(tmp_path):
    (tmp_path / "e.ply").write_bytes(b"")
    fails(tmp_path / "e.ply", InvalidInputError, r"is empty \(0 bytes\)")
    (tmp_path / "n.ply").write_bytes(b"solid cube\nfacet normal 0 0 1\n")
    fails(tmp_path / "n.ply", InvalidInputError, r"not a \.ply file")
    fails(write_ply(tmp_path / "h.ply", end_header=False), InvalidInputError, r"no 'end_header'")
    (tmp_path / "long.ply").write_bytes(b"ply\nformat ascii 1.0\n" + b"x" * 10_000)
    fails(tmp_path / "long.ply", InvalidInputError, r"header line 3 is over 4096 bytes")
    fails(write_ply(tmp_path / "abc.ply", count="abc"), InvalidInputError,
          r"element 'vertex' count 'abc' is not a whole number")
    fails(write_ply(tmp_path / "neg.ply", count="-3"), InvalidInputError, r"count '-3' is not a whole number >= 0")
    fails(write_ply(tmp_path / "nc.ply", count=""), InvalidInputError, r"is not 'element NAME COUNT'")
    fails(write_ply(tmp_path / "dup.ply", props=SPLAT_PROPS + ("x",)), InvalidInputError, r"repeats the properties")
    p = tmp_path / "ty.ply"
    p.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty quaternion x\nend_header\n1\n")
    fails(p, InvalidInputError, r"unknown \.ply property type 'quaternion'")
    p.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float\nend_header\n1\n")
    fails(p, InvalidInputError, r"is not 'property TYPE NAME'")


def test_ply_counts_against_data(tmp_path):
    fails(write_ply(tmp_path / "t.ply", count=5, rows=np.ones((3, len(SPLAT_PROPS)))), InvalidInputError,
          r"truncated \.ply: the header's 5 'vertex' rows need 220 bytes, found 132")
    p = write_ply(tmp_path / "big.ply", count=10**12, rows=np.ones((3, len(SPLAT_PROPS))))
    tracemalloc.start()
    t = time.perf_counter()
    try:
        fails(p, InvalidInputError, r"truncated \.ply: the header's 1000000000000 'vertex' rows")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50e6 and time.perf_counter() - t < 5
    fails(write_ply(tmp_path / "a.ply", count=10**12, rows=np.ones((3, len(SPLAT_PROPS))), fmt="ascii"),
          InvalidInputError, r"declares 1000000000000 rows but the file's ascii data is only \d+ bytes")
    fails(write_ply(tmp_path / "a2.ply", count=4, rows=np.ones((3, len(SPLAT_PROPS))), fmt="ascii"),
          InvalidInputError, r"declares 4 data rows .* the ascii body has 3 lines: fewer rows than declared")
    fails(write_ply(tmp_path / "z.ply", count=0), InvalidInputError, r"holds 0 Gaussians")


def test_ply_properties_and_values(tmp_path):
    fails(write_ply(tmp_path / "nx.ply", props=SPLAT_PROPS[3:]), InvalidInputError,
          r"not a Gaussian splat \.ply: vertex properties \['x', 'y', 'z'\] are missing")
    fails(write_ply(tmp_path / "pts.ply", props=("x", "y", "z")), InvalidInputError,
          r"'scale_0'.*'opacity'\] are missing \(a point cloud")
    fails(write_ply(tmp_path / "no.ply", props=SPLAT_PROPS[:-1]), InvalidInputError,
          r"\['opacity'\] are missing \(found")
    rows = [[1.0] * len(SPLAT_PROPS), [1.0] * 4 + ["abc"] + [1.0] * 6]
    fails(write_ply(tmp_path / "asc.ply", rows=rows, fmt="ascii"), InvalidInputError,
          r"ascii vertex 1: 'abc' is not a number")
    rows = [[1.0] * len(SPLAT_PROPS), [1.0] * 3]
    fails(write_ply(tmp_path / "asc2.ply", rows=rows, fmt="ascii"), InvalidInputError,
          r"ascii vertex 1 has 3 values, the header declares 11")
    nan = np.ones((4, len(SPLAT_PROPS)), np.float32)
    nan[:, 0] = np.nan
    fails(write_ply(tmp_path / "nan.ply", count=4, rows=nan), InvalidInputError, r"no usable Gaussians: all 4")
    (tmp_path / "d.ply").mkdir()
    fails(tmp_path / "d.ply", InvalidInputError, r"is a folder, not a file")


def test_ply_some_non_finite_dropped_with_warning(tmp_path):
    s = tiny_splat(5)
    s["means"][1, 1] = float("inf")
    p = write_splat_ply(tmp_path / "s.ply", s["means"], s["quats"], s["scales"], s["opacities"])
    with pytest.warns(UserWarning, match="dropped 1 Gaussians with NaN/inf"):
        assert len(load_scene(str(p), SceneConfig()).scene) == 4


# ------------------------------------------------------------------------------------------- procedural
@pytest.mark.parametrize("spec", ["procedural:abc", "procedural:5", "procedural:", "procedural:3000:",
                                  "procedural:3000:x", "procedural:3000:1:2", "procedural:-5", "procedural:3000000",
                                  "procedural:999", "procedural:3000:-1", "procedural: 3000"])
def test_procedural_bad_specs(spec):
    fails(spec, InvalidInputError, r"procedural, procedural:N or procedural:N:SEED .*\[1000, 2000000\].*SEED a "
          r"whole number >= 0")


def test_procedural_specs_and_procedural_named_files(tmp_path, monkeypatch):
    a = load_scene("procedural:1000:3", SceneConfig())
    assert a.kind == "procedural" and a.source == "procedural:1000:3"
    assert len(load_scene("procedural:1000", SceneConfig()).room.means) == 1000
    s = tiny_splat(5)
    monkeypatch.chdir(tmp_path)
    write_splat_ply("procedural_room.ply", s["means"], s["quats"], s["scales"], s["opacities"])
    ld = load_scene("procedural_room.ply", SceneConfig())
    assert ld.kind == "ply" and len(ld.scene) == 5
    Path("procedural_bad.ply").write_bytes(b"")
    fails("procedural_bad.ply", InvalidInputError, r"is empty")
    fails("procedural2", InvalidInputError, r"scene not found")


# ------------------------------------------------------------------------------------------- real files, CLI
@pytest.mark.parametrize("path", [REPO / "cinenerf_ns" / "assets" / "room0.npz", FOX_NPZ], ids=["room0", "fox3000"])
def test_real_files_still_load(path, monkeypatch):
    if not path.exists():
        pytest.skip(f"{path} absent")
    monkeypatch.undo()  # the real exports build their (offline) text encoder
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ld = load_scene(str(path), SceneConfig())
    assert ld.kind == "checkpoint" and len(ld.scene) > 1000 and ld.start_region is not None
    assert ld.locate is not None and ld.semantics is not None


def test_cli_prints_one_line(tmp_path, monkeypatch, capsys):
    from cinenerf_ns.cli import plan

    (tmp_path / "x.npz").write_bytes(b"")
    for spec in (str(tmp_path / "x.npz"), "procedural:abc"):
        monkeypatch.setattr(sys, "argv", ["cinesplat-plan", "--scene", spec, "--go-to", "0 0 0", "--look-at", "1 1 1",
                                          "--output-dir", str(tmp_path / "out")])
        with pytest.raises(SystemExit) as ei:
            plan.entrypoint()
        assert ei.value.code == 2
        err = capsys.readouterr().err  # errors go to stderr
        assert "cinesplat-plan: " in err and spec in err.replace("\n", "") and "Traceback" not in err


def test_run_with_malformed_camera_files_loads_without_cameras(tmp_path):
    """A run whose dataset/dataparser json is malformed still loads (no start region), never an IndexError."""
    data, run = tmp_path / "data", tmp_path / "run"
    data.mkdir()
    (run / "nerfstudio_models").mkdir(parents=True)
    sd = {"_model.gauss_params." + k: v for k, v in tiny_splat(8).items()}
    torch.save({"step": 1, "pipeline": sd}, run / "nerfstudio_models" / "step-000000001.ckpt")
    parts = "".join(f"- {p}\n" for p in data.parts)
    (run / "config.yml").write_text(f"method_name: cinesplat\ndata: !!python/object/apply:pathlib.PosixPath\n{parts}")
    (data / "transforms.json").write_text(json.dumps({"frames": [{"transform_matrix": [[1, 0], [0, 1]]}]}))
    (run / "dataparser_transforms.json").write_text(json.dumps({"transform": [[1, 0], [0, 1]], "scale": 1.0}))
    ld = load_scene(str(run / "config.yml"), SceneConfig())
    assert len(ld.scene) > 0 and ld.start_region is None and ld.config_path == run / "config.yml"


def test_preview_of_a_ply_coloured_with_red_green_blue(tmp_path):
    """The preview (cinesplat-plan --preview) draws a .ply's red/green/blue colours, as the viewer does (it drew
    grey)."""
    from cinenerf_ns.scenes import preview_scene

    rgb = np.array([[255, 0, 0], [0, 128, 0], [10, 20, 30]], np.float32)
    rows = np.concatenate([np.ones((3, len(SPLAT_PROPS)), np.float32), rgb], 1)
    p = write_ply(tmp_path / "rgb.ply", props=SPLAT_PROPS + ("red", "green", "blue"), count=3, rows=rows, fmt="ascii")
    np.testing.assert_allclose(preview_scene(load_scene(str(p), SceneConfig())).colors.numpy(), rgb / 255.0, atol=1e-6)


# ------------------------------------------------------------------------------------------- read whole or refused
def test_npz_and_torch_files_with_bytes_after_their_data(tmp_path):
    """A padded array, bytes after a zip archive (.npz or torch's zip format): refused, never read in part."""
    s = tiny_splat(6)
    p = save_npz(tmp_path / "ok.npz", **s)
    assert len(load_scene(str(p), SceneConfig()).scene) > 0
    (tmp_path / "tail.npz").write_bytes(p.read_bytes() + b"\0" * 5)
    fails(tmp_path / "tail.npz", CheckpointError, r"bytes after the end of its zip archive")
    buf = io.BytesIO()
    np.lib.format.write_array(buf, s["means"].numpy())
    with zipfile.ZipFile(tmp_path / "pad.npz", "w") as zf:
        zf.writestr("means.npy", buf.getvalue() + b"\0" * 12)  # more data than the shape (6, 3) holds
        for k in ("quats", "scales", "opacities"):
            b = io.BytesIO()
            np.lib.format.write_array(b, s[k].numpy())
            zf.writestr(f"{k}.npy", b.getvalue())
        b = io.BytesIO()
        np.lib.format.write_array(b, np.array("{}"))
        zf.writestr("info_json.npy", b.getvalue())
    fails(tmp_path / "pad.npz", CheckpointError, r"padded or corrupt: array 'means' claims shape \(6, 3\) \(72 "
          r"bytes\) but stores 84 bytes")
    with zipfile.ZipFile(tmp_path / "dup.npz", "w") as zf, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # zipfile warns of the duplicate name it writes
        for k in ("means", "quats", "scales", "opacities", "means"):
            b = io.BytesIO()
            np.lib.format.write_array(b, s[k].numpy())
            zf.writestr(f"{k}.npy", b.getvalue())
    fails(tmp_path / "dup.npz", CheckpointError, r"holds 'means.npy' more than once: an inconsistent archive")
    st = SplatCheckpoint(SplatParams.of(s["means"], s["quats"], s["scales"], s["opacities"]))
    pt = export_compact(st, tmp_path / "ok.pt")
    (tmp_path / "tail.pt").write_bytes(pt.read_bytes() + b"junk")
    fails(tmp_path / "tail.pt", CheckpointError, r"bytes after the end of its zip archive")
    blob = torch.load(pt, weights_only=True)
    torch.save(blob, tmp_path / "legacy.pt", _use_new_zipfile_serialization=False)  # pickle format, read in order
    assert len(load_scene(str(tmp_path / "legacy.pt"), SceneConfig()).scene) > 0
    (tmp_path / "legacy_tail.pt").write_bytes((tmp_path / "legacy.pt").read_bytes() + b"junk")
    fails(tmp_path / "legacy_tail.pt", CheckpointError, r"has bytes after the end of its data")


@pytest.mark.parametrize("info,problem", [
    ({"start_region": [[0, 0, 0], [1, -1, 1]]}, r"info_json's start_region is inverted or empty along y"),
    ({"start_region": [[0, 0, 0], [1, 1, float("nan")]]}, r"info_json's start_region must be .* finite"),
    ({"camera_centres": [[0, 0]]}, r"info_json's camera_centres must be \[F, 3\]"),
    ({"camera_centres": [[0, 0, float("inf")]]}, r"info_json's camera_centres must be \[F, 3\] finite"),
    ({"camera_poses": [[1, 2, 3]]}, r"info_json's camera_poses must be \[F, 3, 4\]"),
], ids=["inverted", "nan", "centres-shape", "centres-inf", "poses-shape"])
def test_compact_metadata_is_checked_at_load(tmp_path, info, problem):
    p = save_npz(tmp_path / "meta.npz", info=json.dumps(info), **tiny_splat(6))
    fails(p, CheckpointError, problem)


def _semantic_npz(path: Path, n: int = 6, latent_width: int = 3, labels: int = 2, names: int = 2,
                  label_width: int = 24) -> Path:
    from cinenerf_ns.method.codec import CodecConfig, FeatureCodec

    cc = CodecConfig(hidden_dim=16, backend="torch")
    codec = FeatureCodec(24, cc)
    info = {"feature_dim": 24, "codec_config": vars(cc), "codec_backend": "torch",
            "label_names": [f"thing {i}" for i in range(names)]}
    arrays = {**tiny_splat(n), "latents": torch.rand(n, latent_width), "label_embeddings": torch.randn(labels,
                                                                                                      label_width)}
    arrays.update({"codec." + k: v for k, v in codec.state_dict().items()})
    return save_npz(path, info=json.dumps(info), **arrays)


def test_semantic_parts_must_agree(tmp_path):
    """Latents as wide as the codec decodes, one label embedding per label name, as wide as the codec's features
    (they once ended in a traceback, or fell back to a random CLIP without a word)."""
    fails(_semantic_npz(tmp_path / "w.npz", latent_width=5), CheckpointError,
          r"latents are \(6, 5\) but the codec decodes latents of width 3 \(codec_config.latent_dim\)")
    fails(_semantic_npz(tmp_path / "l.npz", labels=3), CheckpointError,
          r"label_embeddings has 3 rows but label_names lists 2 names")
    fails(_semantic_npz(tmp_path / "d.npz", label_width=7), CheckpointError,
          r"label_embeddings are 7 wide but the codec's features are 24 wide")


def test_a_run_whose_dataset_is_gone_says_it_plans_without_its_cameras(tmp_path):
    """Not silently: the note names the config, the missing dataset and what is lost."""
    run = tmp_path / "run"
    (run / "nerfstudio_models").mkdir(parents=True)
    torch.save({"step": 1, "pipeline": {"_model.gauss_params." + k: v for k, v in tiny_splat(8).items()}},
               run / "nerfstudio_models" / "step-000000001.ckpt")
    gone = tmp_path / "data_moved_away"
    parts = "".join(f"- {p}\n" for p in gone.parts)
    (run / "config.yml").write_text(f"method_name: cinesplat\ndata: !!python/object/apply:pathlib.PosixPath\n{parts}")
    ld = load_scene(str(run / "config.yml"), SceneConfig())
    assert ld.start_region is None
    (note,) = ld.notes
    assert f"its dataset {gone} is gone; planning without the training cameras" in note and "config.yml" in note


def test_scene_paths_that_are_not_files(tmp_path):
    import os

    os.symlink(tmp_path / "loop.npz", tmp_path / "loop.npz")
    fails(tmp_path / "loop.npz", InvalidInputError, r"is a symbolic link loop")
    os.mkfifo(tmp_path / "pipe.ckpt")
    fails(tmp_path / "pipe.ckpt", InvalidInputError, r"is a FIFO \(named pipe\), not a regular file")


def test_text_without_loadable_clip_weights_gives_advice_for_this_tool():
    """ClipWeightsError's own advice names ns-train options; the planner's message names what works here."""
    from cinenerf_ns.method.clip_features import ClipWeightsError
    from cinenerf_ns.scenes import LoadedScene, SceneSemantics, resolve_match

    def match(text):
        raise ClipWeightsError("Could not load CLIP weights 'ViT-B-16' / 'laion' (OSError: offline).\n"
                               "  * pass --pipeline.datamanager.clip.checkpoint-path FILE")

    ld = LoadedScene(scene=None, locate=lambda t: None, kind="checkpoint", source="x.npz",
                     semantics=SceneSemantics(None, ["red armchair", "floor lamp"], True, match))
    with pytest.raises(InvalidInputError) as e:
        resolve_match("a cosy corner", ld, "go-to")
    msg = str(e.value)
    assert "--pipeline" not in msg and "Could not load CLIP weights 'ViT-B-16'" in msg
    assert "give the go-to target as a point 'x y z', or one of the scene's object names: red armchair, floor lamp" \
        in msg


def test_a_malformed_stored_planning_region_is_a_checkpoint_error():
    from cinenerf_ns.scenes import stored_region

    assert stored_region({}, "x.npz") is None
    lo, hi = stored_region({"planning_region": {"lo": [0, 0, 0], "hi": [1, 2, 3]}}, "x.npz")
    np.testing.assert_allclose(hi, [1, 2, 3])
    for bad in ({"lo": [0, 0, 0], "hi": [0, 1, 1]}, {"lo": [0, 0]}, "everywhere"):
        with pytest.raises(CheckpointError, match="x.npz: its stored planning region is not a valid box"):
            stored_region({"planning_region": bad}, "x.npz")


@pytest.mark.parametrize("bad,msg", [
    ({"lo": [0, 0, 0], "hi": [1, -1, 1]}, "info_json's planning_region is empty or inverted along y"),
    ({"lo": [0, 0, 0], "hi": [1, float("nan"), 1]}, "info_json's planning_region must be 6 finite numbers"),
    ({"lo": [0, 0, 0]}, "info_json's planning_region must be {\"lo\": \\[x, y, z\\], \"hi\": \\[x, y, z\\]}"),
    ([0, 0, 0, 1, 1, 1], "info_json's planning_region must be {\"lo\""),
])
def test_a_stored_planning_region_is_checked_when_the_file_loads(bad, msg):
    from cinenerf_ns.method.scene_files import check_info

    check_info({"planning_region": {"lo": [0, 0, 0], "hi": [1, 2, 3]}}, Path("x.npz"), "info_json")
    with pytest.raises(CheckpointError, match=f"x.npz: {msg}"):
        check_info({"planning_region": bad}, Path("x.npz"), "info_json")
