"""Small readers for triangle meshes (PLY ascii/binary, Wavefront OBJ) and ModelNet text clouds.

Convention:
    Returns vertices [V, 3] float64 (file units; metres for OCRTOC/YCB) and faces [F, 3] int64 (polygons are
    fan-triangulated). Only geometry is read (colours, normals, texture coordinates are skipped).
"""
from __future__ import annotations

import pathlib

import numpy as np

from equipose.core.errors import ConfigError

__all__ = ["read_mesh", "read_ply", "read_obj", "read_modelnet_txt"]

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _fan(polys) -> np.ndarray:
    tris = [(p[0], p[i], p[i + 1]) for p in polys for i in range(1, len(p) - 1)]
    return np.asarray(tris, dtype=np.int64).reshape(-1, 3)


def read_ply(path) -> tuple:
    """(vertices [V, 3], faces [F, 3]) from an ascii or binary_little_endian PLY."""
    path = pathlib.Path(path)
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            raise ConfigError(f"{path} is not a PLY file")
        fmt, elements = None, []
        while True:
            line = f.readline()
            if not line:
                raise ConfigError(f"{path}: PLY header has no end_header")
            tok = line.decode("ascii", "replace").split()
            if not tok:
                continue
            if tok[0] == "format":
                fmt = tok[1]
            elif tok[0] == "element":
                elements.append({"name": tok[1], "count": int(tok[2]), "props": []})
            elif tok[0] == "property":
                if tok[1] == "list":
                    elements[-1]["props"].append((tok[4], "list", tok[2], tok[3]))
                else:
                    elements[-1]["props"].append((tok[2], tok[1]))
            elif tok[0] == "end_header":
                break
        body = f.read()
    verts, faces = None, None
    if fmt == "ascii":
        lines = body.decode("ascii", "replace").split("\n")
        pos = 0
        for el in elements:
            rows = lines[pos:pos + el["count"]]
            pos += el["count"]
            if el["name"] == "vertex":
                names = [p[0] for p in el["props"]]
                arr = np.array([r.split()[:len(names)] for r in rows], dtype=np.float64)
                verts = arr[:, [names.index(c) for c in "xyz"]]
            elif el["name"] == "face":
                polys = []
                for r in rows:
                    v = r.split()
                    n = int(v[0])
                    polys.append([int(x) for x in v[1:1 + n]])
                faces = _fan(polys)
    elif fmt == "binary_little_endian":
        off = 0
        for el in elements:
            if all(p[1] != "list" for p in el["props"]):
                dt = np.dtype([(p[0], "<" + _PLY_TYPES[p[1]]) for p in el["props"]])
                arr = np.frombuffer(body, dtype=dt, count=el["count"], offset=off)
                off += dt.itemsize * el["count"]
                if el["name"] == "vertex":
                    verts = np.stack([arr[c].astype(np.float64) for c in "xyz"], 1)
                continue
            polys = []
            for _ in range(el["count"]):              # list elements: walk record by record
                rec = []
                for p in el["props"]:
                    if p[1] == "list":
                        ct, it = np.dtype("<" + _PLY_TYPES[p[2]]), np.dtype("<" + _PLY_TYPES[p[3]])
                        n = int(np.frombuffer(body, ct, 1, off)[0])
                        off += ct.itemsize
                        vals = np.frombuffer(body, it, n, off)
                        off += it.itemsize * n
                        if p[0] in ("vertex_indices", "vertex_index"):
                            rec = vals.astype(np.int64).tolist()
                    else:
                        off += np.dtype(_PLY_TYPES[p[1]]).itemsize
                polys.append(rec)
            if el["name"] == "face":
                faces = _fan(polys)
    else:
        raise ConfigError(f"{path}: unsupported PLY format {fmt!r}")
    if verts is None or faces is None:
        raise ConfigError(f"{path}: PLY without vertex or face element")
    return verts, faces


def read_obj(path) -> tuple:
    """(vertices [V, 3], faces [F, 3]) from a Wavefront OBJ (``v`` and ``f`` records; 1-based or negative indices)."""
    verts, polys = [], []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                idx = [int(tok.split("/")[0]) for tok in line.split()[1:]]
                polys.append([i - 1 if i > 0 else len(verts) + i for i in idx])
    if not verts or not polys:
        raise ConfigError(f"{path}: OBJ without vertices or faces")
    return np.asarray(verts, np.float64), _fan(polys)


def read_mesh(path) -> tuple:
    """Dispatch on the suffix (.ply / .obj)."""
    suffix = pathlib.Path(path).suffix.lower()
    if suffix == ".ply":
        return read_ply(path)
    if suffix == ".obj":
        return read_obj(path)
    raise ConfigError(f"unsupported mesh format {suffix!r} (use .ply or .obj)")


def read_modelnet_txt(path) -> tuple:
    """(points [P, 3], normals [P, 3]) from a ModelNet ``*_normal_resampled`` text cloud (``.txt`` or ``.txt.gz``)."""
    a = np.loadtxt(path, delimiter=",")
    return a[:, :3], a[:, 3:6]
