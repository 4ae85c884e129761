import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

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


# --- the body must hold exactly what the header declares (issue 38: a truncated scene was planned against) ---

NAMES = ["x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "opacity"]


def _header(fmt: str, n: int, extra: str = "") -> str:
    return (f"ply\nformat {fmt} 1.0\nelement vertex {n}\n" + "".join(f"property float {p}\n" for p in NAMES)
            + extra + "end_header\n")


def _rows(n: int, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, len(NAMES))).astype(np.float32)
    v[:, 6] = 1.0  # a usable rotation
    return v


def _all_refused(tmp_path, cases):
    """Each case (file content, message regex) is refused with a message naming the file."""
    from cinenerf_ns.planner.scene.ply import read_ply_vertices

    for case, (data, regex) in cases.items():
        p = tmp_path / f"{case}.ply"
        p.write_bytes(data if isinstance(data, bytes) else data.encode())
        with pytest.raises(InvalidInputError, match=regex) as e:
            read_ply_vertices(p)
        assert str(p) in str(e.value), case


def _ascii(rows) -> str:
    return "".join(" ".join(repr(float(x)) for x in r) + "\n" for r in rows)


@pytest.mark.parametrize("order,fmt", [("<", "binary_little_endian"), (">", "binary_big_endian")])
def test_binary_header_must_match_the_body(tmp_path, order, fmt):
    from cinenerf_ns.planner.scene.ply import read_ply_vertices

    v = _rows(10)
    body = v.astype(order + "f4").tobytes()
    ok = tmp_path / "ok.ply"
    ok.write_bytes(_header(fmt, 10).encode() + body)
    back = read_ply_vertices(ok)
    assert back.dtype["x"].isnative  # big-endian files come back in native order: torch reads them
    np.testing.assert_array_equal(np.stack([back[n] for n in NAMES], -1), v)
    cases = {
        "fewer-declared": (_header(fmt, 7).encode() + body, r"bytes after the last element .*\(7 'vertex'\)"),
        "padded": (_header(fmt, 10).encode() + body + b"\0" * 3, r"3 bytes after the last element"),
        "newline-after": (_header(fmt, 10).encode() + body + b"\n", r"1 bytes after the last element"),
        "cut-short": (_header(fmt, 10).encode() + body[:-4], r"truncated"),
        "more-declared": (_header(fmt, 11).encode() + body, r"truncated"),
    }
    _all_refused(tmp_path, cases)


def test_big_endian_splat_loads_as_obstacles(tmp_path):
    """A big-endian 3DGS .ply is planned with, not refused with numpy's byte-order wording."""
    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene

    v = _rows(6)
    v[:, 10] = 3.0
    for order, fmt in (("<", "binary_little_endian"), (">", "binary_big_endian")):
        (tmp_path / f"{fmt}.ply").write_bytes(_header(fmt, 6).encode() + v.astype(order + "f4").tobytes())
    le = EllipsoidScene.from_ply(tmp_path / "binary_little_endian.ply")
    be = EllipsoidScene.from_ply(tmp_path / "binary_big_endian.ply")
    torch.testing.assert_close(be.means, le.means)
    torch.testing.assert_close(be.radii, le.radii)


def test_list_elements_are_walked_to_check_the_size(tmp_path):
    """A face element (list property) before or after the vertices is skipped exactly; its rows count too."""
    from cinenerf_ns.planner.scene.ply import read_ply_vertices

    v = _rows(4)
    faces_head = "element face 2\nproperty list uchar int vertex_indices\n"
    faces = np.array([3], "u1").tobytes() + np.arange(3, dtype="<i4").tobytes()
    faces += np.array([4], "u1").tobytes() + np.arange(4, dtype="<i4").tobytes()
    after = _header("binary_little_endian", 4, faces_head).encode() + v.astype("<f4").tobytes() + faces
    (tmp_path / "after.ply").write_bytes(after)
    np.testing.assert_array_equal(read_ply_vertices(tmp_path / "after.ply")["x"], v[:, 0])
    (tmp_path / "after_cut.ply").write_bytes(after[:-2])
    with pytest.raises(InvalidInputError, match="'face' .* (past the end|need)"):
        read_ply_vertices(tmp_path / "after_cut.ply")
    (tmp_path / "after_pad.ply").write_bytes(after + b"\1")
    with pytest.raises(InvalidInputError, match="1 bytes after the last element"):
        read_ply_vertices(tmp_path / "after_pad.ply")
    before = ("ply\nformat binary_little_endian 1.0\n" + faces_head + _header("", 4)[len("ply\nformat  1.0\n"):])
    (tmp_path / "before.ply").write_bytes(before.encode() + faces + v.astype("<f4").tobytes())
    np.testing.assert_array_equal(read_ply_vertices(tmp_path / "before.ply")["opacity"], v[:, 10])


def test_ascii_header_must_match_the_body(tmp_path):
    from cinenerf_ns.planner.scene.ply import read_ply_vertices

    v = _rows(5)
    head = _header("ascii", 5)
    (tmp_path / "ok.ply").write_text(head + _ascii(v) + "\n\n")  # trailing blank lines are not rows
    np.testing.assert_allclose(read_ply_vertices(tmp_path / "ok.ply")["y"], v[:, 1])
    lines = _ascii(v).splitlines(keepends=True)
    cases = {
        "fewer-declared": (_header("ascii", 3) + _ascii(v), r"declares 3 data rows .* 5 lines: more rows"),
        "more-declared": (_header("ascii", 9) + _ascii(v), r"declares 9 data rows .* 5 lines: fewer rows"),
        "short-row": (head + "".join(lines[:2]) + "1 2 3\n" + "".join(lines[3:]),
                      r"ascii vertex 2 has 3 values, the header declares 11"),
        "long-row": (head + lines[0].rstrip() + " 7\n" + "".join(lines[1:]), r"ascii vertex 0 has 12 values"),
        "not-a-number": (head + "".join(lines[:3]) + lines[3].replace(lines[3].split()[2], "abc", 1) + lines[4],
                         r"ascii vertex 3: 'abc' is not a number"),
        "blank-line-inside": (head + "".join(lines[:2]) + "\n" + "".join(lines[2:4]), r"rows|blank"),
    }
    _all_refused(tmp_path, cases)


def test_an_element_declared_twice_is_refused(tmp_path):
    two = _header("binary_little_endian", 1, "element vertex 1\nproperty float x\n").encode()
    _all_refused(tmp_path, {"two": (two + _rows(1).tobytes() + np.zeros(1, "<f4").tobytes(),
                                    r"declares the element\(s\) \['vertex'\] more than once")})


def test_ascii_integer_properties_are_not_wrapped(tmp_path):
    head = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty uchar red\nend_header\n"
    _all_refused(tmp_path, {"over": (head + "1 2\n3 300\n", r"ascii vertex 1: red = 300 does not fit its type uchar"),
                            "nan": (head + "1 nan\n3 4\n", r"ascii vertex 0: red = nan does not fit"),
                            "fraction": (head + "1 2.5\n3 4\n", r"red = 2.5 does not fit")})


def test_ascii_with_a_face_element_and_a_size_limit(tmp_path, monkeypatch):
    from cinenerf_ns.planner.scene import ply

    v = _rows(3)
    head = _header("ascii", 3, "element face 1\nproperty list uchar int vertex_indices\n")
    (tmp_path / "f.ply").write_text(head + _ascii(v) + "3 0 1 2\n")
    np.testing.assert_allclose(ply.read_ply_vertices(tmp_path / "f.ply")["z"], v[:, 2])
    (tmp_path / "g.ply").write_text(head + _ascii(v))
    with pytest.raises(InvalidInputError, match="declares 4 data rows"):
        ply.read_ply_vertices(tmp_path / "g.ply")
    monkeypatch.setattr(ply, "MAX_ASCII_BYTES", 100)
    with pytest.raises(InvalidInputError, match="over the 0 MiB .* convert it to a binary .ply"):
        ply.read_ply_vertices(tmp_path / "f.ply")


def test_links_loops_and_fifos_are_named_for_what_they_are(tmp_path):
    import os

    loop = tmp_path / "loop.ply"
    os.symlink(loop, loop)
    with pytest.raises(InvalidInputError, match="symbolic link loop"):
        read_splat_ply(loop)
    broken = tmp_path / "broken.ply"
    os.symlink(tmp_path / "gone.ply", broken)
    with pytest.raises(InvalidInputError, match="broken symbolic link"):
        read_splat_ply(broken)
    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)
    with pytest.raises(InvalidInputError, match="FIFO"):  # refused without opening it (an open would block)
        read_splat_ply(fifo)
    with pytest.raises(InvalidInputError, match="is a folder"):
        read_splat_ply(tmp_path)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(0, 40), fmt=st.sampled_from(["binary_little_endian", "binary_big_endian", "ascii"]),
       cut=st.integers(-9, 9), seed=st.integers(0, 10_000))
def test_any_body_that_differs_from_its_header_is_refused(n, fmt, cut, seed):
    """Round trip of a body written here in each format; the same body with bytes cut or added (cut != 0; for
    ascii: whole rows) is refused, never read in part."""
    import tempfile
    from pathlib import Path

    from cinenerf_ns.planner.scene.ply import read_ply_vertices

    rng = np.random.default_rng(seed)
    props = [("x", "f4", "float"), ("k", "i4", "int"), ("c", "u1", "uchar"), ("d", "f8", "double")]
    order = ">" if fmt == "binary_big_endian" else "<"
    rows = np.empty(n, dtype=[(p, order + t) for p, t, _ in props])
    rows["x"], rows["d"] = rng.normal(size=n), rng.normal(size=n)
    rows["k"], rows["c"] = rng.integers(-1000, 1000, n), rng.integers(0, 256, n)
    head = (f"ply\nformat {fmt} 1.0\nelement vertex {n}\n" + "".join(f"property {w} {p}\n" for p, _, w in props)
            + "end_header\n").encode()
    if fmt == "ascii":
        lines = [f"{float(r['x'])!r} {int(r['k'])} {int(r['c'])} {float(r['d'])!r}\n" for r in rows]
        extra = [f"{i} {i} {i} {i}\n" for i in range(max(cut, 0))]
        body = "".join(lines[:max(n + min(cut, 0), 0)] + extra).encode()
        changed = len(lines[:max(n + min(cut, 0), 0)] + extra) != n
        whole = "".join(lines).encode()
    else:
        whole = rows.tobytes()
        body = whole[:max(len(whole) + cut, 0)] if cut < 0 else whole + bytes(cut)
        changed = body != whole
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "v.ply"
        p.write_bytes(head + whole)
        back = read_ply_vertices(p)
        for name, _, _ in props:
            np.testing.assert_array_equal(back[name], rows[name])
        p.write_bytes(head + body)
        if changed:
            with pytest.raises(InvalidInputError, match=str(p)):
                read_ply_vertices(p)
