#!/usr/bin/env python3
"""Casts the same primary rays as `cac bench render` with Embree (embreex, via trimesh's mesh
loading) and prints one JSON line: {"build_ms", "rays", "seconds", "rays_per_s", "hits"}.

Usage: embree_bench.py MESH.npz RAYS.bin REPEATS
MESH.npz holds `vertices` (n,3 float32) and `faces` (m,3 int32); RAYS.bin is float32 rows of
(ox, oy, oz, dx, dy, dz). Dev-only: `cac bench render` calls it when embreex is installed.
"""
import json
import sys
import time

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

mesh = np.load(sys.argv[1])
rays = np.fromfile(sys.argv[2], dtype=np.float32).reshape(-1, 6)
repeats = int(sys.argv[3])
v = mesh["vertices"].astype(np.float32)
f = mesh["faces"].astype(np.int32)
t0 = time.perf_counter()
scene = rtcore_scene.EmbreeScene()
TriangleMesh(scene, v[f])
origins = np.ascontiguousarray(rays[:, :3])
dirs = np.ascontiguousarray(rays[:, 3:])
scene.run(origins[:1], dirs[:1])  # commit/build
build = time.perf_counter() - t0
best = float("inf")
hits = 0
for _ in range(repeats):
    t = time.perf_counter()
    ids = scene.run(origins, dirs)
    best = min(best, time.perf_counter() - t)
    hits = int((ids >= 0).sum())
print(json.dumps({"build_ms": build * 1e3, "rays": len(rays), "seconds": best,
                  "rays_per_s": len(rays) / best, "hits": hits}))
