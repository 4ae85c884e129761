"""Read and write ``.ply`` files: the project's one .ply reader and writer (numpy only, no plyfile).

Why our own reader: a scene file may be anything a user points the tools at. ``read_ply_vertices`` checks every size a
header claims against the file before it allocates or reads (a count of 10^12 vertices in a small file is refused at
once, with the file named), requires the body to hold exactly what the header declares (too few or too many rows and
trailing bytes are refused: a scene read in part would be planned through the objects it left out), and reports every
malformed header or body as one InvalidInputError that says what is wrong; plyfile trusts the header and fails with
its own exceptions (and is not in the GPU machines' wheel set). Splat scenes (``read_splat_ply``), training seed point
clouds (synthetic/dataset.py, method/compat.py) and the viewer all read through it; ``write_ply_vertices`` is the one
writer.

The 3DGS layout (Kerbl et al., also written by ``ns-export gaussian-splat``) is one ``vertex`` element
with float properties ``x y z`` (means), ``scale_0..2`` (log scales), ``rot_0..3`` (quaternion, wxyz),
``opacity`` (logit), ``f_dc_0..2`` (SH DC colour) and ``f_rest_*`` (higher SH bands); ``nx ny nz``
are usually present and unused. A file without ``f_dc_*`` may colour its Gaussians with ``red green blue``.
Binary (little or big endian, returned in native byte order) and ascii bodies (numpy's parser, up to MAX_ASCII_BYTES)
are read.
"""
from __future__ import annotations

import io
import os
import re
from pathlib import Path
from typing import Dict, Optional, Union

import numpy as np

from ..atomic import atomic_write
from ..errors import InvalidInputError
from ..file_checks import path_problem
from .splat_params import SplatParams, rgb_to_dc

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
REQUIRED = ("x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "opacity")
RGB = ("red", "green", "blue")
_MAX_HEADER_LINE = 4096  # bytes; a longer "line" is binary data, not a header
_MAX_HEADER_LINES = 100_000


def _element(tok, path: Path, lineno: int):
    """[name, count, []] of an 'element NAME COUNT' header line."""
    if len(tok) != 3:
        raise InvalidInputError(f"{path}: .ply header line {lineno} {' '.join(tok)!r} is not 'element NAME COUNT'")
    if not tok[2].isdigit():
        raise InvalidInputError(f"{path}: .ply header line {lineno}: element {tok[1]!r} count {tok[2]!r} is not a "
                                f"whole number >= 0")
    return [tok[1], int(tok[2]), []]


def _property(tok, path: Path, lineno: int):
    """(name, dtype) or (name, ('list', count_t, item_t)) of a 'property ...' header line."""
    is_list = len(tok) > 1 and tok[1] == "list"
    if len(tok) != (5 if is_list else 3):
        want = "property list COUNT_TYPE ITEM_TYPE NAME" if is_list else "property TYPE NAME"
        raise InvalidInputError(f"{path}: .ply header line {lineno} {' '.join(tok)!r} is not '{want}'")
    types = tok[2:4] if is_list else tok[1:2]
    bad = [t for t in types if t not in _PLY_TYPES]
    if bad:
        raise InvalidInputError(f"{path}: unknown .ply property type {bad[0]!r} (header line {lineno})")
    if is_list:
        return tok[4], ("list", _PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]])
    return tok[2], _PLY_TYPES[tok[1]]


def _parse_header(f, path: Path):
    first = f.readline(_MAX_HEADER_LINE)
    if not first:
        raise InvalidInputError(f"{path} is empty (0 bytes): not a .ply file")
    if first.strip() != b"ply":
        raise InvalidInputError(f"{path} is not a .ply file (first line {first[:20]!r}, want 'ply')")
    fmt = None
    elements = []  # [name, count, [(prop_name, dtype or ('list', count_t, item_t))]]
    for lineno in range(2, _MAX_HEADER_LINES):
        line = f.readline(_MAX_HEADER_LINE)
        if not line:
            raise InvalidInputError(f"{path}: .ply header has no 'end_header' line (truncated file?)")
        if not line.endswith(b"\n") and len(line) == _MAX_HEADER_LINE:
            raise InvalidInputError(f"{path}: .ply header line {lineno} is over {_MAX_HEADER_LINE} bytes long: "
                                    f"no 'end_header' before binary data (corrupt header?)")
        tok = line.decode("ascii", errors="replace").split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "end_header":
            break
        if tok[0] == "format":
            fmt = tok[1] if len(tok) > 1 else None
        elif tok[0] == "element":
            elements.append(_element(tok, path, lineno))
        elif tok[0] == "property":
            if not elements:
                raise InvalidInputError(f"{path}: .ply property before any element")
            elements[-1][2].append(_property(tok, path, lineno))
    else:
        raise InvalidInputError(f"{path}: .ply header has no 'end_header' in {_MAX_HEADER_LINES} lines")
    if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
        raise InvalidInputError(f"{path}: unsupported .ply format {fmt!r}")
    enames = [name for name, _, _ in elements]
    if len(set(enames)) != len(enames):
        raise InvalidInputError(f"{path}: .ply header declares the element(s) "
                                f"{sorted({n for n in enames if enames.count(n) > 1})} more than once")
    for name, _, props in elements:
        names = [p for p, _ in props]
        dup = sorted({p for p in names if names.count(p) > 1})
        if dup:
            raise InvalidInputError(f"{path}: .ply element {name!r} repeats the properties {dup}")
    return fmt, elements


def read_ply_vertices(path: Union[str, Path]) -> np.ndarray:
    """The ``vertex`` element of a .ply file as a numpy structured array [N] (native byte order). The body must
    hold exactly what the header declares: too few or too many rows, or bytes after the last element, are refused
    with the file named (a truncated or padded scene is never read in part)."""
    path = Path(path)
    problem = path_problem(path)
    if problem is not None:
        raise InvalidInputError(f"scene file {path} {problem}")
    with open(path, "rb") as f:
        fmt, elements = _parse_header(f, path)
        data_bytes = os.fstat(f.fileno()).st_size - f.tell()
        if not any(name == "vertex" for name, _, _ in elements):
            raise InvalidInputError(f"{path}: .ply file has no 'vertex' element")
        if fmt == "ascii":
            return _read_ascii(f, path, elements, data_bytes)
        return _read_binary(f, path, "<" if fmt == "binary_little_endian" else ">", elements, data_bytes)


MAX_ASCII_BYTES = 1 << 30  # an ascii .ply body over 1 GiB is refused (binary is ~3x smaller and read at disk speed)


def _read_ascii(f, path: Path, elements, data_bytes: int) -> np.ndarray:
    """The vertex rows of an ascii .ply body (one line per element row, every element's rows counted)."""
    total = sum(count for _, count, _ in elements)
    if total * 2 > data_bytes + 1:  # a row is at least one digit and a newline
        raise InvalidInputError(f"{path}: .ply header declares {total} rows but the file's ascii data is only "
                                f"{data_bytes} bytes (truncated file?)")
    if data_bytes > MAX_ASCII_BYTES:
        raise InvalidInputError(f"{path}: ascii .ply body of {data_bytes / 2**20:.0f} MiB is over the "
                                f"{MAX_ASCII_BYTES >> 20} MiB this tool reads as text; convert it to a binary .ply")
    body = f.read().rstrip()
    ends = np.flatnonzero(np.frombuffer(body, np.uint8) == ord("\n"))
    lines = len(ends) + 1 if body else 0
    if lines != total:
        what = "fewer" if lines < total else "more"
        raise InvalidInputError(f"{path}: .ply header declares {total} data rows "
                                f"({', '.join(f'{c} {n!r}' for n, c, _ in elements)}) but the ascii body has "
                                f"{lines} lines: {what} rows than declared (truncated file, or a header count that "
                                f"does not match the data)")
    pos = 0
    for name, count, props in elements:
        if name != "vertex":
            pos += count
            continue
        if any(isinstance(t, tuple) for _, t in props):
            raise InvalidInputError(f"{path}: list properties in 'vertex' are not supported")
        first = 0 if pos == 0 else int(ends[pos - 1]) + 1
        last = len(body) if pos + count >= lines else int(ends[pos + count - 1])
        arr = np.empty(count, dtype=np.dtype([(p, t) for p, t in props]))
        if count == 0:
            return arr
        try:
            data = np.loadtxt(io.BytesIO(body[first:last]), dtype=np.float64, comments=None, ndmin=2)
        except ValueError:
            raise InvalidInputError(f"{path}: {_ascii_problem(body[first:last], len(props))}") from None
        if data.shape != (count, len(props)):
            raise InvalidInputError(f"{path}: ascii vertex data has {data.shape[0]} rows of {data.shape[1]} values; "
                                    f"the header declares {count} rows of {len(props)} properties (blank lines?)")
        for k, (p, t) in enumerate(props):
            col = data[:, k]
            if np.dtype(t).kind in "iu":  # an integer property takes whole numbers in its range, never wrapped
                lim = np.iinfo(np.dtype(t))
                bad = np.flatnonzero(~((col == np.round(col)) & (col >= lim.min) & (col <= lim.max)))
                if bad.size:
                    raise InvalidInputError(f"{path}: ascii vertex {bad[0]}: {p} = {col[bad[0]]:g} does not fit its "
                                            f"type {_PLY_NAMES[t]} (whole numbers in [{lim.min}, {lim.max}])")
            arr[p] = col
        return arr
    raise AssertionError("unreachable: the vertex element was checked")


def _ascii_problem(block: bytes, nprops: int) -> str:
    """Where an ascii vertex block that numpy could not parse goes wrong (the error path only: a Python scan)."""
    for i, line in enumerate(block.splitlines()):
        vals = line.split()
        if len(vals) != nprops:
            return f"ascii vertex {i} has {len(vals)} values, the header declares {nprops} properties"
        for v in vals:
            try:
                float(v)
            except ValueError:
                return f"ascii vertex {i}: {v[:40].decode('ascii', 'replace')!r} is not a number"
    return "unreadable ascii vertex data"


def _element_bytes(buf: bytes, offset: int, name: str, count: int, props, endian: str, path: Path) -> int:
    """Bytes the ``count`` rows of an element take in a binary body from ``offset``, list properties walked."""
    if not any(isinstance(t, tuple) for _, t in props):
        return np.dtype([(p, endian + t) for p, t in props]).itemsize * count
    start = offset
    for row in range(count):
        for _, t in props:
            if not isinstance(t, tuple):
                offset += np.dtype(t).itemsize
                continue
            ct, it = np.dtype(endian + t[1]), np.dtype(t[2])
            if offset + ct.itemsize > len(buf):
                raise InvalidInputError(f"{path}: truncated .ply: element {name!r} row {row} of {count} runs past "
                                        f"the end of the file")
            n = int(np.frombuffer(buf, dtype=ct, count=1, offset=offset)[0])
            if n < 0:
                raise InvalidInputError(f"{path}: .ply element {name!r} row {row}: negative list length {n}")
            offset += ct.itemsize + n * it.itemsize
        if offset > len(buf):
            break
    return offset - start


def _read_binary(f, path: Path, endian: str, elements, data_bytes: int) -> np.ndarray:
    """The vertex rows of a binary .ply body; the header's sizes are checked against the file size before reading,
    and the elements must fill the body exactly."""
    low = 0  # the body's size without list properties: a lower bound, checked before anything is read
    for name, count, props in elements:
        if not any(isinstance(t, tuple) for _, t in props):
            need = np.dtype([(p, endian + t) for p, t in props]).itemsize * count
            if low + need > data_bytes:
                raise InvalidInputError(
                    f"{path}: truncated .ply: the header's {count} {name!r} rows need {need} bytes, "
                    f"found {max(data_bytes - low, 0)} (header count too large or file cut short)")
            low += need
    fixed = not any(isinstance(t, tuple) for _, _, props in elements for _, t in props)
    if fixed and low != data_bytes:  # the exact size is known: refused before a byte of a padded file is read
        _trailing(path, data_bytes - low, elements)
    buf = f.read()
    offset, vertex = 0, None
    for name, count, props in elements:
        need = _element_bytes(buf, offset, name, count, props, endian, path)
        if offset + need > len(buf):
            raise InvalidInputError(
                f"{path}: truncated .ply: the header's {count} {name!r} rows need {need} bytes, "
                f"found {max(len(buf) - offset, 0)} (header count too large or file cut short)")
        if name == "vertex":
            if any(isinstance(t, tuple) for _, t in props):
                raise InvalidInputError(f"{path}: list properties in 'vertex' are not supported")
            dt = np.dtype([(p, endian + t) for p, t in props])
            native = np.dtype([(p, t) for p, t in props])  # big-endian files: torch takes native order only
            vertex = np.frombuffer(buf, dtype=dt, count=count, offset=offset).astype(native, copy=False)
        offset += need
    if offset != len(buf):
        _trailing(path, len(buf) - offset, elements)
    return vertex


def _trailing(path: Path, extra: int, elements) -> None:
    raise InvalidInputError(
        f"{path}: .ply holds {extra} bytes after the last element its header declares "
        f"({', '.join(f'{c} {n!r}' for n, c, _ in elements)}): the header's counts do not match the data "
        f"(a header count too small, or a padded or concatenated file); refusing to read it in part")


def unit_rgb(rgb: np.ndarray) -> np.ndarray:
    """.ply colours [N, 3] (red, green, blue) in [0, 1] (float32): integers and floats above 1 are 0..255 values."""
    out = rgb.astype(np.float32)
    if rgb.dtype.kind != "f" or (out.size and out.max() > 1.0):
        out = out / np.float32(255.0)
    return np.clip(out, 0.0, 1.0)


def _numbered(names, prefix: str):
    ks = sorted((int(m.group(1)), n) for n in names if (m := re.fullmatch(prefix + r"(\d+)", n)))
    return [n for _, n in ks]


def read_splat_ply(path: Union[str, Path]) -> SplatParams:
    """Splat parameters of a standard 3DGS .ply (see module docstring). InvalidInputError when a property is
    missing, the file holds no Gaussian, or no Gaussian has all-finite parameters."""
    v = read_ply_vertices(path)
    names = v.dtype.names or ()
    missing = [p for p in REQUIRED if p not in names]
    if missing:
        cloud = len(missing) == len(REQUIRED) - 3 and "x" not in missing  # positions only (colours, normals)
        points = " (a point cloud: each Gaussian needs scale_*, rot_* and opacity)" if cloud else ""
        raise InvalidInputError(
            f"{path} is not a Gaussian splat .ply: vertex properties {missing} are missing{points} "
            f"(found {list(names)[:20]}{'...' if len(names) > 20 else ''}); export one with `ns-export gaussian-splat` "
            f"or give the run's config.yml"
        )
    if len(v) == 0:
        raise InvalidInputError(f"{path} holds 0 Gaussians (element vertex 0)")

    def cols(ns):
        return np.stack([np.asarray(v[n]) for n in ns], axis=-1)

    q = cols(("rot_0", "rot_1", "rot_2", "rot_3")).astype(np.float64)
    usable = (np.isfinite(cols(("x", "y", "z", "opacity")).astype(np.float64)).all(-1) & np.isfinite(q).all(-1)
              & (np.linalg.norm(q, axis=-1) > 1e-12) & ~np.isnan(cols(("scale_0", "scale_1", "scale_2"))).any(-1))
    if not usable.any():
        raise InvalidInputError(f"{path} has no usable Gaussians: all {len(v)} have NaN/inf positions or parameters "
                                f"(or zero rotations)")

    dc = _numbered(names, "f_dc_")
    rest = _numbered(names, "f_rest_")
    rgb = RGB if not dc and set(RGB) <= set(names) else ()  # a file with plain colours instead of SH
    known = set(REQUIRED) | set(dc) | set(rest) | set(rgb) | {"nx", "ny", "nz"}
    return SplatParams(
        means=cols(("x", "y", "z")),
        quats_wxyz=cols(("rot_0", "rot_1", "rot_2", "rot_3")),
        log_scales=cols(("scale_0", "scale_1", "scale_2")),
        opacity_logits=np.asarray(v["opacity"]).copy(),
        colors_dc=cols(dc) if dc else rgb_to_dc(unit_rgb(cols(rgb))) if rgb else None,
        sh_rest=cols(rest) if rest else None,
        extra={n: np.asarray(v[n]).copy() for n in names if n not in known},
    )


_PLY_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint", "f4": "float",
              "f8": "double"}


def write_ply_vertices(path: Union[str, Path], rec: np.ndarray) -> Path:
    """Write a structured array [N] as the ``vertex`` element of a binary little-endian .ply (atomic: temp file +
    rename); its fields are the properties, in order (numeric scalars: float, double, (u)char, (u)short, (u)int)."""
    names = rec.dtype.names or ()
    props = []
    for n in names:
        t = rec.dtype.fields[n][0]
        key = f"{t.kind}{t.itemsize}"
        if t.shape or key not in _PLY_NAMES:
            raise InvalidInputError(f"write_ply_vertices: field {n!r} has type {t}, which a .ply property cannot hold")
        props.append((n, key))
    le = np.dtype([(n, "<" + k) for n, k in props])
    header = "ply\nformat binary_little_endian 1.0\n" f"element vertex {len(rec)}\n"
    header += "".join(f"property {_PLY_NAMES[k]} {n}\n" for n, k in props) + "end_header\n"
    return atomic_write(path, header.encode("ascii") + rec.astype(le).tobytes())


def write_splat_ply(
    path: Union[str, Path],
    means,  # [N, 3]
    quats,  # [N, 4] wxyz
    log_scales,  # [N, 3]
    opacity_logits,  # [N] or [N, 1]
    colors_dc=None,  # [N, 3] or None (zeros written)
    extra: Optional[Dict[str, object]] = None,  # name -> [N] (or [N, K] written as name_0..name_{K-1})
) -> Path:
    """Write a binary little-endian float32 3DGS .ply (atomic: temp file + rename).

    Accepts numpy arrays or torch tensors. ``extra={"f_rest": sh[N, 45]}`` writes f_rest_0..44."""

    def arr(x, name, width=None):
        if hasattr(x, "detach"):
            x = x.detach().cpu().numpy()
        x = np.asarray(x, dtype=np.float32)
        if width is None:
            x = x.reshape(-1)
        elif x.ndim != 2 or x.shape[1] != width:
            raise InvalidInputError(f"write_splat_ply: {name} must be [N, {width}], got {x.shape}")
        return x

    m = arr(means, "means", 3)
    n = m.shape[0]
    cols = {"x": m[:, 0], "y": m[:, 1], "z": m[:, 2]}
    zeros = np.zeros(n, np.float32)
    cols.update(nx=zeros, ny=zeros, nz=zeros)
    dc = np.zeros((n, 3), np.float32) if colors_dc is None else arr(colors_dc, "colors_dc", 3)
    cols.update({f"f_dc_{i}": dc[:, i] for i in range(3)})
    for name, val in (extra or {}).items():
        a = val.detach().cpu().numpy() if hasattr(val, "detach") else np.asarray(val)
        a = a.astype(np.float32)
        if a.ndim == 1:
            cols[name] = a
        elif a.ndim == 2:
            cols.update({f"{name}_{i}": a[:, i] for i in range(a.shape[1])})
        else:
            raise InvalidInputError(f"write_splat_ply: extra[{name!r}] must be [N] or [N, K], got {a.shape}")
    cols["opacity"] = arr(opacity_logits, "opacity_logits")
    ls, q = arr(log_scales, "log_scales", 3), arr(quats, "quats", 4)
    cols.update({f"scale_{i}": ls[:, i] for i in range(3)})
    cols.update({f"rot_{i}": q[:, i] for i in range(4)})
    for k, c in cols.items():
        if c.shape != (n,):
            raise InvalidInputError(f"write_splat_ply: property {k} has {c.shape[0]} rows, means have {n}")
    rec = np.empty(n, dtype=np.dtype([(k, "<f4") for k in cols]))
    for k, c in cols.items():
        rec[k] = c
    return write_ply_vertices(path, rec)
