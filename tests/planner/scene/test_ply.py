import numpy as np
import pytest
import torch

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.ply import read_splat_ply, write_splat_ply


def _params(n=50, seed=0):
    g = np.random.default_rng(seed)
    return (g.normal(size=(n, 3)), g.normal(size=(n, 4)), g.normal(size=(n, 3)) - 3, g.normal(size=n),
            g.normal(size=(n, 3)))


def test_round_trip(tmp_path):
    m, q, s, o, c = _params()
    rest = np.random.default_rng(1).normal(size=(50, 45))
    p = write_splat_ply(tmp_path / "a.ply", m, q, s, o, colors_dc=c, extra={"f_rest": rest, "foo": np.arange(50)})
    sp = read_splat_ply(p)
    f32 = lambda x: np.asarray(x, np.float32)
    np.testing.assert_array_equal(sp.means, f32(m))
    np.testing.assert_array_equal(sp.quats_wxyz, f32(q))
    np.testing.assert_array_equal(sp.log_scales, f32(s))
    np.testing.assert_array_equal(sp.opacity_logits, f32(o))
    np.testing.assert_array_equal(sp.colors_dc, f32(c))
    np.testing.assert_array_equal(sp.sh_rest, f32(rest))  # f_rest_10 sorted numerically, not as text
    np.testing.assert_array_equal(sp.extra["foo"], np.arange(50, dtype=np.float32))


def test_torch_inputs_and_standard_layout(tmp_path):
    m, q, s, o, _ = _params(7)
    p = write_splat_ply(tmp_path / "b.ply", torch.tensor(m), torch.tensor(q), torch.tensor(s), torch.tensor(o)[:, None])
    head = p.read_bytes().split(b"end_header")[0].decode()
    for prop in ("x", "nx", "f_dc_0", "opacity", "scale_2", "rot_3"):
        assert f"property float {prop}\n" in head
    assert read_splat_ply(p).means.shape == (7, 3)


def test_big_endian_and_ascii(tmp_path):
    names = ["x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "opacity"]
    vals = np.arange(2 * len(names), dtype=np.float32).reshape(2, -1)
    head = "ply\nformat {}\nelement vertex 2\n" + "".join(f"property float {n}\n" for n in names) + "end_header\n"
    (tmp_path / "be.ply").write_bytes(head.format("binary_big_endian 1.0").encode() + vals.astype(">f4").tobytes())
    (tmp_path / "as.ply").write_text(head.format("ascii 1.0") + "\n".join(" ".join(map(str, r)) for r in vals) + "\n")
    for f in ("be.ply", "as.ply"):
        sp = read_splat_ply(tmp_path / f)
        np.testing.assert_array_equal(sp.means, vals[:, :3])
        np.testing.assert_array_equal(sp.opacity_logits, vals[:, 10])


def test_missing_file_and_properties(tmp_path):
    with pytest.raises(InvalidInputError, match="not found"):
        read_splat_ply(tmp_path / "nope.ply")
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
            "property float x\nproperty float y\nproperty float z\nend_header\n")
    (tmp_path / "pts.ply").write_bytes(head.encode() + np.zeros(3, "<f4").tobytes())
    with pytest.raises(InvalidInputError, match="missing"):
        read_splat_ply(tmp_path / "pts.ply")
    (tmp_path / "junk.ply").write_bytes(b"hello")
    with pytest.raises(InvalidInputError, match="not a .ply"):
        read_splat_ply(tmp_path / "junk.ply")


def test_truncated(tmp_path):
    m, q, s, o, _ = _params(5)
    p = write_splat_ply(tmp_path / "t.ply", m, q, s, o)
    p.write_bytes(p.read_bytes()[:-10])
    with pytest.raises(InvalidInputError, match="truncated"):
        read_splat_ply(p)



def rgb_ply(path, rgb):
    """A splat .ply of len(rgb) Gaussians coloured with red/green/blue (uchar) instead of f_dc_*."""
    names = ["x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "opacity"]
    dt = np.dtype([(n, "<f4") for n in names] + [(c, "u1") for c in ("red", "green", "blue")])
    rec = np.zeros(len(rgb), dt)
    rec["rot_0"], rec["opacity"] = 1.0, 2.0
    rec["red"], rec["green"], rec["blue"] = np.asarray(rgb, np.uint8).T
    head = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(rgb)}\n"
    head += "".join(f"property float {n}\n" for n in names)
    head += "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    path.write_bytes(head.encode() + rec.tobytes())
    return path


def test_plain_rgb_colours_when_there_is_no_sh(tmp_path):
    """red/green/blue are the colour of a .ply without f_dc_* (0..255 integers, or floats in [0, 1])."""
    rgb = np.array([[255, 0, 0], [0, 128, 0], [10, 20, 30]], np.uint8)
    sp = read_splat_ply(rgb_ply(tmp_path / "rgb.ply", rgb))
    np.testing.assert_allclose(sp.rgb(), rgb / 255.0, atol=1e-6)
    assert "red" not in sp.extra


@pytest.mark.parametrize("text", [False, True])
@pytest.mark.parametrize("byte_order", ["<", ">"])
def test_reads_what_plyfile_writes_and_writes_what_plyfile_reads(tmp_path, text, byte_order):
    """The project's reader and writer agree with an independent implementation (plyfile, a test dependency)."""
    plyfile = pytest.importorskip("plyfile")
    from cinenerf_ns.planner.scene.ply import read_ply_vertices, write_ply_vertices

    rng = np.random.default_rng(0)
    v = np.empty(20, dtype=[("x", "f4"), ("y", "f8"), ("red", "u1"), ("k", "i4"), ("s", "i2")])
    v["x"], v["y"] = rng.normal(size=20), rng.normal(size=20)
    v["red"], v["k"], v["s"] = rng.integers(0, 256, 20), rng.integers(-1000, 1000, 20), rng.integers(-99, 99, 20)
    theirs = tmp_path / "theirs.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")], text=text, byte_order=byte_order).write(str(theirs))
    back = read_ply_vertices(theirs)
    for k in v.dtype.names:
        np.testing.assert_array_equal(back[k], v[k], err_msg=k)
    ours = write_ply_vertices(tmp_path / "ours.ply", v)
    read = plyfile.PlyData.read(str(ours))["vertex"].data
    for k in v.dtype.names:
        np.testing.assert_array_equal(read[k], v[k], err_msg=k)
        assert read[k].dtype.kind == v[k].dtype.kind and read[k].dtype.itemsize == v[k].dtype.itemsize
