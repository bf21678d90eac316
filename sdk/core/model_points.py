"""An object's own model as points for instance-level mode (``PoseEstimator(model_points=...)``), read from a file.

Convention: returns [M, 3] float64 metres in the model's own (CAD) frame. Point files: ``.xyz`` / ``.txt`` / ``.csv``
/ ``.pts`` (one point per line, the first three numbers x y z, separated by spaces or commas; lines starting with
``#`` skipped), ``.npy`` ([M, ≥ 3]), ``.pcd`` (fields x, y, z; via pypcd4). Meshes: ``.obj`` and ``.ply`` (ASCII or
binary little-endian; faces triangles or polygons, fanned into triangles) are sampled on their surface, ``MESH_POINTS``
points spread by area from a fixed seed, so the same file gives the same points; a ``.ply`` without faces is read as
points. ``unit``: "m", "mm", "cm" or metres per file unit as a number (CAD files are often in millimetres).
Bad files raise ``InvalidPointsError`` saying what is wrong.
"""
from __future__ import annotations

import pathlib

import numpy as np

from equipose.core.errors import InvalidPointsError
from equipose.core.units import metres_per_unit

__all__ = ["MESH_POINTS", "load_model_points", "sample_surface"]

MESH_POINTS = 4096          # points sampled on a mesh's surface
_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def load_model_points(path, unit="m") -> np.ndarray:
    """The model points of ``path`` (see the module docstring) → [M, 3] float64 metres."""
    path = pathlib.Path(path)
    scale = _unit_scale(unit)
    if not path.is_file():
        raise InvalidPointsError(f"model points: {path} is not a file")
    ext = path.suffix.lower()
    if ext in (".xyz", ".txt", ".csv", ".pts"):
        pts = _read_text(path)
    elif ext == ".npy":
        pts = np.load(path, allow_pickle=False)
    elif ext == ".pcd":
        pts = _read_pcd(path)
    elif ext == ".obj":
        pts = sample_surface(*_read_obj(path))
    elif ext == ".ply":
        vertices, faces = _read_ply(path)
        pts = vertices if faces is None or not len(faces) else sample_surface(vertices, faces)
    else:
        raise InvalidPointsError(f"model points: {path.name} — unknown file type {ext!r}; use .xyz/.txt/.csv/.pts, "
                                 ".npy, .pcd, .obj or .ply")
    pts = np.asarray(pts, np.float64)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise InvalidPointsError(f"model points: {path.name} holds an array of shape {pts.shape}; need [M, 3] x y z")
    pts = pts[:, :3] * scale
    if not np.all(np.isfinite(pts)):
        raise InvalidPointsError(f"model points: {path.name} holds NaN or Inf coordinates")
    return pts


def sample_surface(vertices: np.ndarray, triangles: np.ndarray, count: int = MESH_POINTS, seed: int = 0):
    """``count`` points on the triangles' surface, by area (seeded). Convention: ``vertices`` [V, 3],
    ``triangles`` [F, 3] int (indices into ``vertices``) → [count, 3] in the vertices' unit."""
    V = np.asarray(vertices, np.float64)
    T = np.asarray(triangles, np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or T.ndim != 2 or T.shape[1] != 3 or not len(T):
        raise InvalidPointsError(f"mesh: need vertices [V, 3] and triangles [F ≥ 1, 3], got {V.shape}, {T.shape}")
    if T.min() < 0 or T.max() >= len(V):
        raise InvalidPointsError(f"mesh: a face refers to vertex {int(T.max()) if T.max() >= len(V) else int(T.min())}"
                                 f" of {len(V)}")
    a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]                                # [F, 3] each
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)                 # [F]
    if not area.sum() > 0:
        raise InvalidPointsError("mesh: every face has zero area")
    rng = np.random.default_rng(seed)
    f = rng.choice(len(T), size=count, p=area / area.sum())                     # [count] faces, by area
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    return (1 - s)[:, None] * a[f] + (s * (1 - r2))[:, None] * b[f] + (s * r2)[:, None] * c[f]


def _unit_scale(unit) -> float:
    return metres_per_unit(unit, "model points unit", InvalidPointsError, "file unit")


def _read_text(path) -> np.ndarray:
    rows = []
    for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            rows.append([float(v) for v in parts[:3]])
        except ValueError:
            raise InvalidPointsError(f"model points: {path.name} line {n}: {line[:60]!r} is not x y z numbers") from None
        if len(rows[-1]) < 3:
            raise InvalidPointsError(f"model points: {path.name} line {n} holds {len(rows[-1])} numbers; need x y z")
    if not rows:
        raise InvalidPointsError(f"model points: {path.name} holds no points")
    return np.array(rows)


def _read_pcd(path) -> np.ndarray:
    try:
        from pypcd4 import PointCloud
    except ImportError:
        raise InvalidPointsError("reading .pcd needs pypcd4 (a dependency of equipose): pip install pypcd4") from None
    try:
        pc = PointCloud.from_path(str(path))
        pts = pc.numpy(("x", "y", "z"))
    except Exception as e:  # pypcd4 raises assorted errors for malformed files
        raise InvalidPointsError(f"model points: {path.name} is not a readable PCD with x, y, z fields "
                                 f"({type(e).__name__}: {str(e)[:120]})") from None
    return pts[np.all(np.isfinite(pts), axis=1)]


def _fan(polygon: list) -> list:
    """A polygon's vertex indices → its triangles as a fan from the first vertex."""
    return [[polygon[0], polygon[i], polygon[i + 1]] for i in range(1, len(polygon) - 1)]


def _read_obj(path) -> tuple:
    vertices, faces = [], []
    for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        try:
            if parts[0] == "v":
                vertices.append([float(v) for v in parts[1:4]])
            elif parts[0] == "f":
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                idx = [i - 1 if i > 0 else len(vertices) + i for i in idx]      # 1-based; negative: relative
                faces.extend(_fan(idx))
        except ValueError:
            raise InvalidPointsError(f"model points: {path.name} line {n}: {line[:60]!r} is not a valid v/f line") \
                from None
    if not vertices or not faces:
        raise InvalidPointsError(f"model points: {path.name} holds {len(vertices)} vertices and {len(faces)} faces; "
                                 "an .obj needs both (for points alone use .xyz)")
    return np.array(vertices), np.array(faces)


def _read_ply(path) -> tuple:
    """(vertices [V, 3], triangles [F, 3] or None) of a PLY file."""
    data = path.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise InvalidPointsError(f"model points: {path.name} is not a PLY file (no 'ply' … 'end_header' header)")
    header = data[:end].decode("ascii", errors="replace").splitlines()
    body = data[data.index(b"\n", end) + 1:]
    fmt, elements = None, []                                                    # [(name, count, [properties])]
    for line in header:
        w = line.split()
        if not w:
            continue
        if w[0] == "format":
            fmt = w[1]
        elif w[0] == "element":
            elements.append((w[1], int(w[2]), []))
        elif w[0] == "property" and elements:
            elements[-1][2].append(w[1:])
    if fmt not in ("ascii", "binary_little_endian"):
        raise InvalidPointsError(f"model points: {path.name}: PLY format {fmt!r} is not read (ascii or "
                                 "binary_little_endian)")
    if fmt == "ascii":
        return _ply_ascii(path, body, elements)
    return _ply_binary(path, body, elements)


def _vertex_columns(path, props) -> list:
    names = [p[-1] for p in props]
    if not all(k in names for k in ("x", "y", "z")):
        raise InvalidPointsError(f"model points: {path.name}: its vertices have no x, y, z properties ({names})")
    return [names.index(k) for k in ("x", "y", "z")]


def _ply_ascii(path, body: bytes, elements) -> tuple:
    lines = iter(body.decode("ascii", errors="replace").split("\n"))
    vertices, faces = None, []
    try:
        for name, count, props in elements:
            rows = [next(lines).split() for _ in range(count)]
            if name == "vertex":
                cols = _vertex_columns(path, props)
                vertices = np.array([[float(r[c]) for c in cols] for r in rows])
            elif name == "face":
                for r in rows:
                    k = int(r[0])
                    faces.extend(_fan([int(v) for v in r[1:1 + k]]))
    except (StopIteration, ValueError, IndexError):
        raise InvalidPointsError(f"model points: {path.name}: the ASCII PLY body does not match its header") from None
    if vertices is None:
        raise InvalidPointsError(f"model points: {path.name} has no vertex element")
    return vertices, (np.array(faces) if faces else None)


def _ply_binary(path, body: bytes, elements) -> tuple:
    vertices, faces, offset = None, None, 0
    for name, count, props in elements:
        if any(p[0] == "list" for p in props):                                  # faces: a list of indices
            if name != "face" or len(props) != 1:
                raise InvalidPointsError(f"model points: {path.name}: binary PLY element {name!r} with list "
                                         "properties is not read (only a face element of vertex indices)")
            count_t, index_t = _PLY_TYPES.get(props[0][1]), _PLY_TYPES.get(props[0][2])
            if count_t is None or index_t is None:
                raise InvalidPointsError(f"model points: {path.name}: unknown PLY list types {props[0][1:3]}")
            dt = np.dtype([("n", "<" + count_t), ("i", "<" + index_t, 3)])      # triangles only
            if offset + count * dt.itemsize > len(body):
                raise InvalidPointsError(f"model points: {path.name}: the file ends inside its faces (binary PLY "
                                         "faces must all be triangles)")
            rec = np.frombuffer(body, dt, count=count, offset=offset)
            if count and not np.all(rec["n"] == 3):
                raise InvalidPointsError(f"model points: {path.name}: binary PLY faces must all be triangles")
            faces, offset = rec["i"].astype(np.int64), offset + count * dt.itemsize
            continue
        try:
            dt = np.dtype([(p[-1], "<" + _PLY_TYPES[p[0]]) for p in props])
        except KeyError as e:
            raise InvalidPointsError(f"model points: {path.name}: unknown PLY property type {e.args[0]!r}") from None
        if offset + count * dt.itemsize > len(body):
            raise InvalidPointsError(f"model points: {path.name}: the file ends inside its {name!r} element")
        rec = np.frombuffer(body, dt, count=count, offset=offset)
        offset += count * dt.itemsize
        if name == "vertex":
            _vertex_columns(path, props)
            vertices = np.stack([rec["x"], rec["y"], rec["z"]], 1).astype(np.float64)
    if vertices is None:
        raise InvalidPointsError(f"model points: {path.name} has no vertex element")
    return vertices, faces
