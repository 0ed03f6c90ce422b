"""Generate scenes/teapot.ply: the Utah teapot (Martin Newell, 1975; public domain) tessellated from its
32 bicubic Bézier patches and 306 control points, which are embedded below (the classic "teaset" data;
no download).

Run from the project root: `python scripts/make_teapot.py` (rewrites the file; tests check that the
committed file is what this script writes, byte for byte).

The mesh, in the scene's frame (metres, y up): the base's centre at the origin, the body's axis along +y,
the spout towards +x and the handle towards −x (the data's x stays x, its z becomes y, its y becomes −z).
Size: HEIGHT = 0.35 m from the base to the top of the lid's knob (the data's 3.15 units): 0.715 m from
handle to spout tip and 0.444 m across the body, since the Utah proportions are long (spout and handle reach
3.4 and 3.0 units from the axis, the body's radius is 2). That is the top of a household teapot's range
(roughly 0.15–0.35 m tall), chosen in the calibration of scenes/pi_hallway.xml: the NLOS information grows
steeply with the teapot's size (about as its height^4.5 there). Tessellation: SEGMENTS × SEGMENTS quads per
patch, two triangles each; vertices shared between patches are welded (so Mitsuba's recomputed vertex
normals are smooth) and triangles with a repeated vertex (the knob's and the base's poles) are dropped. Every
patch is oriented outwards (a ray-parity vote, below; in the classic data all 32 patches turn out to need
flipping), so the triangles' normals point out of the pot; the scene still gives it a two-sided BSDF, since
the gap between lid and rim shows the inside.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

HEIGHT = 0.35       # m, base to the top of the knob (a household teapot is roughly 0.15–0.35 m tall)
SEGMENTS = 8        # quads per patch side: 32 · 8 · 8 · 2 = 4096 triangles before dropping degenerate ones
OUT = Path(__file__).resolve().parents[1] / "scenes" / "teapot.ply"

# The 306 control points (x y z, data units; z up, the base at z = 0), three per line, separated by '|'.
_POINTS = """
    1.4 0.0 2.4 | 1.4 -0.784 2.4 | 0.784 -1.4 2.4
    0.0 -1.4 2.4 | 1.3375 0.0 2.53125 | 1.3375 -0.749 2.53125
    0.749 -1.3375 2.53125 | 0.0 -1.3375 2.53125 | 1.4375 0.0 2.53125
    1.4375 -0.805 2.53125 | 0.805 -1.4375 2.53125 | 0.0 -1.4375 2.53125
    1.5 0.0 2.4 | 1.5 -0.84 2.4 | 0.84 -1.5 2.4
    0.0 -1.5 2.4 | -0.784 -1.4 2.4 | -1.4 -0.784 2.4
    -1.4 0.0 2.4 | -0.749 -1.3375 2.53125 | -1.3375 -0.749 2.53125
    -1.3375 0.0 2.53125 | -0.805 -1.4375 2.53125 | -1.4375 -0.805 2.53125
    -1.4375 0.0 2.53125 | -0.84 -1.5 2.4 | -1.5 -0.84 2.4
    -1.5 0.0 2.4 | -1.4 0.784 2.4 | -0.784 1.4 2.4
    0.0 1.4 2.4 | -1.3375 0.749 2.53125 | -0.749 1.3375 2.53125
    0.0 1.3375 2.53125 | -1.4375 0.805 2.53125 | -0.805 1.4375 2.53125
    0.0 1.4375 2.53125 | -1.5 0.84 2.4 | -0.84 1.5 2.4
    0.0 1.5 2.4 | 0.784 1.4 2.4 | 1.4 0.784 2.4
    0.749 1.3375 2.53125 | 1.3375 0.749 2.53125 | 0.805 1.4375 2.53125
    1.4375 0.805 2.53125 | 0.84 1.5 2.4 | 1.5 0.84 2.4
    1.75 0.0 1.875 | 1.75 -0.98 1.875 | 0.98 -1.75 1.875
    0.0 -1.75 1.875 | 2.0 0.0 1.35 | 2.0 -1.12 1.35
    1.12 -2.0 1.35 | 0.0 -2.0 1.35 | 2.0 0.0 0.9
    2.0 -1.12 0.9 | 1.12 -2.0 0.9 | 0.0 -2.0 0.9
    -0.98 -1.75 1.875 | -1.75 -0.98 1.875 | -1.75 0.0 1.875
    -1.12 -2.0 1.35 | -2.0 -1.12 1.35 | -2.0 0.0 1.35
    -1.12 -2.0 0.9 | -2.0 -1.12 0.9 | -2.0 0.0 0.9
    -1.75 0.98 1.875 | -0.98 1.75 1.875 | 0.0 1.75 1.875
    -2.0 1.12 1.35 | -1.12 2.0 1.35 | 0.0 2.0 1.35
    -2.0 1.12 0.9 | -1.12 2.0 0.9 | 0.0 2.0 0.9
    0.98 1.75 1.875 | 1.75 0.98 1.875 | 1.12 2.0 1.35
    2.0 1.12 1.35 | 1.12 2.0 0.9 | 2.0 1.12 0.9
    2.0 0.0 0.45 | 2.0 -1.12 0.45 | 1.12 -2.0 0.45
    0.0 -2.0 0.45 | 1.5 0.0 0.225 | 1.5 -0.84 0.225
    0.84 -1.5 0.225 | 0.0 -1.5 0.225 | 1.5 0.0 0.15
    1.5 -0.84 0.15 | 0.84 -1.5 0.15 | 0.0 -1.5 0.15
    -1.12 -2.0 0.45 | -2.0 -1.12 0.45 | -2.0 0.0 0.45
    -0.84 -1.5 0.225 | -1.5 -0.84 0.225 | -1.5 0.0 0.225
    -0.84 -1.5 0.15 | -1.5 -0.84 0.15 | -1.5 0.0 0.15
    -2.0 1.12 0.45 | -1.12 2.0 0.45 | 0.0 2.0 0.45
    -1.5 0.84 0.225 | -0.84 1.5 0.225 | 0.0 1.5 0.225
    -1.5 0.84 0.15 | -0.84 1.5 0.15 | 0.0 1.5 0.15
    1.12 2.0 0.45 | 2.0 1.12 0.45 | 0.84 1.5 0.225
    1.5 0.84 0.225 | 0.84 1.5 0.15 | 1.5 0.84 0.15
    -1.6 0.0 2.025 | -1.6 -0.3 2.025 | -1.5 -0.3 2.25
    -1.5 0.0 2.25 | -2.3 0.0 2.025 | -2.3 -0.3 2.025
    -2.5 -0.3 2.25 | -2.5 0.0 2.25 | -2.7 0.0 2.025
    -2.7 -0.3 2.025 | -3.0 -0.3 2.25 | -3.0 0.0 2.25
    -2.7 0.0 1.8 | -2.7 -0.3 1.8 | -3.0 -0.3 1.8
    -3.0 0.0 1.8 | -1.5 0.3 2.25 | -1.6 0.3 2.025
    -2.5 0.3 2.25 | -2.3 0.3 2.025 | -3.0 0.3 2.25
    -2.7 0.3 2.025 | -3.0 0.3 1.8 | -2.7 0.3 1.8
    -2.7 0.0 1.575 | -2.7 -0.3 1.575 | -3.0 -0.3 1.35
    -3.0 0.0 1.35 | -2.5 0.0 1.125 | -2.5 -0.3 1.125
    -2.65 -0.3 0.9375 | -2.65 0.0 0.9375 | -2.0 -0.3 0.9
    -1.9 -0.3 0.6 | -1.9 0.0 0.6 | -3.0 0.3 1.35
    -2.7 0.3 1.575 | -2.65 0.3 0.9375 | -2.5 0.3 1.125
    -1.9 0.3 0.6 | -2.0 0.3 0.9 | 1.7 0.0 1.425
    1.7 -0.66 1.425 | 1.7 -0.66 0.6 | 1.7 0.0 0.6
    2.6 0.0 1.425 | 2.6 -0.66 1.425 | 3.1 -0.66 0.825
    3.1 0.0 0.825 | 2.3 0.0 2.1 | 2.3 -0.25 2.1
    2.4 -0.25 2.025 | 2.4 0.0 2.025 | 2.7 0.0 2.4
    2.7 -0.25 2.4 | 3.3 -0.25 2.4 | 3.3 0.0 2.4
    1.7 0.66 0.6 | 1.7 0.66 1.425 | 3.1 0.66 0.825
    2.6 0.66 1.425 | 2.4 0.25 2.025 | 2.3 0.25 2.1
    3.3 0.25 2.4 | 2.7 0.25 2.4 | 2.8 0.0 2.475
    2.8 -0.25 2.475 | 3.525 -0.25 2.49375 | 3.525 0.0 2.49375
    2.9 0.0 2.475 | 2.9 -0.15 2.475 | 3.45 -0.15 2.5125
    3.45 0.0 2.5125 | 2.8 0.0 2.4 | 2.8 -0.15 2.4
    3.2 -0.15 2.4 | 3.2 0.0 2.4 | 3.525 0.25 2.49375
    2.8 0.25 2.475 | 3.45 0.15 2.5125 | 2.9 0.15 2.475
    3.2 0.15 2.4 | 2.8 0.15 2.4 | 0.0 0.0 3.15
    0.0 -0.002 3.15 | 0.002 0.0 3.15 | 0.8 0.0 3.15
    0.8 -0.45 3.15 | 0.45 -0.8 3.15 | 0.0 -0.8 3.15
    0.0 0.0 2.85 | 0.2 0.0 2.7 | 0.2 -0.112 2.7
    0.112 -0.2 2.7 | 0.0 -0.2 2.7 | -0.002 0.0 3.15
    -0.45 -0.8 3.15 | -0.8 -0.45 3.15 | -0.8 0.0 3.15
    -0.112 -0.2 2.7 | -0.2 -0.112 2.7 | -0.2 0.0 2.7
    0.0 0.002 3.15 | -0.8 0.45 3.15 | -0.45 0.8 3.15
    0.0 0.8 3.15 | -0.2 0.112 2.7 | -0.112 0.2 2.7
    0.0 0.2 2.7 | 0.45 0.8 3.15 | 0.8 0.45 3.15
    0.112 0.2 2.7 | 0.2 0.112 2.7 | 0.4 0.0 2.55
    0.4 -0.224 2.55 | 0.224 -0.4 2.55 | 0.0 -0.4 2.55
    1.3 0.0 2.55 | 1.3 -0.728 2.55 | 0.728 -1.3 2.55
    0.0 -1.3 2.55 | 1.3 0.0 2.4 | 1.3 -0.728 2.4
    0.728 -1.3 2.4 | 0.0 -1.3 2.4 | -0.224 -0.4 2.55
    -0.4 -0.224 2.55 | -0.4 0.0 2.55 | -0.728 -1.3 2.55
    -1.3 -0.728 2.55 | -1.3 0.0 2.55 | -0.728 -1.3 2.4
    -1.3 -0.728 2.4 | -1.3 0.0 2.4 | -0.4 0.224 2.55
    -0.224 0.4 2.55 | 0.0 0.4 2.55 | -1.3 0.728 2.55
    -0.728 1.3 2.55 | 0.0 1.3 2.55 | -1.3 0.728 2.4
    -0.728 1.3 2.4 | 0.0 1.3 2.4 | 0.224 0.4 2.55
    0.4 0.224 2.55 | 0.728 1.3 2.55 | 1.3 0.728 2.55
    0.728 1.3 2.4 | 1.3 0.728 2.4 | 0.0 0.0 0.0
    1.5 0.0 0.15 | 1.5 0.84 0.15 | 0.84 1.5 0.15
    0.0 1.5 0.15 | 1.5 0.0 0.075 | 1.5 0.84 0.075
    0.84 1.5 0.075 | 0.0 1.5 0.075 | 1.425 0.0 0.0
    1.425 0.798 0.0 | 0.798 1.425 0.0 | 0.0 1.425 0.0
    -0.84 1.5 0.15 | -1.5 0.84 0.15 | -1.5 0.0 0.15
    -0.84 1.5 0.075 | -1.5 0.84 0.075 | -1.5 0.0 0.075
    -0.798 1.425 0.0 | -1.425 0.798 0.0 | -1.425 0.0 0.0
    -1.5 -0.84 0.15 | -0.84 -1.5 0.15 | 0.0 -1.5 0.15
    -1.5 -0.84 0.075 | -0.84 -1.5 0.075 | 0.0 -1.5 0.075
    -1.425 -0.798 0.0 | -0.798 -1.425 0.0 | 0.0 -1.425 0.0
    0.84 -1.5 0.15 | 1.5 -0.84 0.15 | 0.84 -1.5 0.075
    1.5 -0.84 0.075 | 0.798 -1.425 0.0 | 1.425 -0.798 0.0
"""

# The 32 patches: 16 control-point indices each (0-based), row by row (4 × 4). Patches 0–3 rim, 4–11 body,
# 12–15 handle, 16–19 spout, 20–23 lid knob, 24–27 lid, 28–31 base.
_PATCHES = """
    0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15
    3 16 17 18 7 19 20 21 11 22 23 24 15 25 26 27
    18 28 29 30 21 31 32 33 24 34 35 36 27 37 38 39
    30 40 41 0 33 42 43 4 36 44 45 8 39 46 47 12
    12 13 14 15 48 49 50 51 52 53 54 55 56 57 58 59
    15 25 26 27 51 60 61 62 55 63 64 65 59 66 67 68
    27 37 38 39 62 69 70 71 65 72 73 74 68 75 76 77
    39 46 47 12 71 78 79 48 74 80 81 52 77 82 83 56
    56 57 58 59 84 85 86 87 88 89 90 91 92 93 94 95
    59 66 67 68 87 96 97 98 91 99 100 101 95 102 103 104
    68 75 76 77 98 105 106 107 101 108 109 110 104 111 112 113
    77 82 83 56 107 114 115 84 110 116 117 88 113 118 119 92
    120 121 122 123 124 125 126 127 128 129 130 131 132 133 134 135
    123 136 137 120 127 138 139 124 131 140 141 128 135 142 143 132
    132 133 134 135 144 145 146 147 148 149 150 151 68 152 153 154
    135 142 143 132 147 155 156 144 151 157 158 148 154 159 160 68
    161 162 163 164 165 166 167 168 169 170 171 172 173 174 175 176
    164 177 178 161 168 179 180 165 172 181 182 169 176 183 184 173
    173 174 175 176 185 186 187 188 189 190 191 192 193 194 195 196
    176 183 184 173 188 197 198 185 192 199 200 189 196 201 202 193
    203 203 203 203 206 207 208 209 210 210 210 210 211 212 213 214
    203 203 203 203 209 216 217 218 210 210 210 210 214 219 220 221
    203 203 203 203 218 223 224 225 210 210 210 210 221 226 227 228
    203 203 203 203 225 229 230 206 210 210 210 210 228 231 232 211
    211 212 213 214 233 234 235 236 237 238 239 240 241 242 243 244
    214 219 220 221 236 245 246 247 240 248 249 250 244 251 252 253
    221 226 227 228 247 254 255 256 250 257 258 259 253 260 261 262
    228 231 232 211 256 263 264 233 259 265 266 237 262 267 268 241
    269 269 269 269 278 279 280 281 274 275 276 277 270 271 272 273
    269 269 269 269 281 288 289 290 277 285 286 287 273 282 283 284
    269 269 269 269 290 297 298 299 287 294 295 296 284 291 292 293
    269 269 269 269 299 304 305 278 296 302 303 274 293 300 301 270
"""


def control_points() -> np.ndarray:
    """The 306 control points (306, 3) float64 in data units (z up)."""
    pts = np.array([[float(x) for x in p.split()] for p in _POINTS.replace("\n", "|").split("|") if p.strip()])
    if pts.shape != (306, 3):
        raise ValueError(f"teapot data: expected 306 control points, parsed {pts.shape}")
    return pts


def patch_indices() -> np.ndarray:
    """The 32 patches' control-point indices (32, 4, 4) int64."""
    idx = np.array([[int(i) for i in line.split()] for line in _PATCHES.strip().splitlines()])
    if idx.shape != (32, 16):
        raise ValueError(f"teapot data: expected 32 patches of 16 indices, parsed {idx.shape}")
    return idx.reshape(32, 4, 4)


def _bernstein(t: np.ndarray) -> np.ndarray:
    """Cubic Bernstein basis (len(t), 4) at parameters t ∈ [0, 1]."""
    t = t[:, None]
    return np.hstack([(1 - t) ** 3, 3 * t * (1 - t) ** 2, 3 * t ** 2 * (1 - t), t ** 3])


def _patch_grid(cp: np.ndarray, n: int) -> np.ndarray:
    """Points (n+1, n+1, 3) of the bicubic patch with control points cp (4, 4, 3) on a uniform (u, v) grid."""
    B = _bernstein(np.linspace(0.0, 1.0, n + 1))
    return np.einsum("ui,vj,ijk->uvk", B, B, cp)


def _ray_hits(orig: np.ndarray, d: np.ndarray, tri: np.ndarray) -> int:
    """Number of triangles tri (T, 3, 3) hit by the ray orig + t·d, t > 0 (Möller–Trumbore)."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = orig - tri[:, 0]
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    return int((ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)).sum())


def _outward(grids: list[np.ndarray], tris: np.ndarray) -> list[bool]:
    """For each patch grid: True if its (u, v) orientation (normal ∂P/∂u × ∂P/∂v) points out of the pot.
    Vote: from a point just off the patch's centre along that normal, count crossings of the whole mesh
    along 15 fixed directions; an even count means outside (majority over the directions, as the pot is
    not watertight: the lid sits in the rim with a gap)."""
    dirs = np.random.default_rng(7).normal(size=(15, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    out = []
    for g in grids:
        m = g.shape[0] // 2
        du, dv = g[m + 1, m] - g[m - 1, m], g[m, m + 1] - g[m, m - 1]
        nrm = np.cross(du, dv)
        nrm /= np.linalg.norm(nrm)
        probe = g[m, m] + 1e-3 * nrm
        outside = sum(_ray_hits(probe, d, tris) % 2 == 0 for d in dirs)
        out.append(outside > len(dirs) // 2)
    return out


def mesh(height: float = HEIGHT, segments: int = SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """The tessellated teapot: vertices (V, 3) float32 in metres (scene frame, y up, base centre at the
    origin, spout towards +x) and triangles (T, 3) uint32, wound counter-clockwise seen from outside."""
    cp, idx = control_points(), patch_indices()
    grids = [_patch_grid(cp[ix], segments) for ix in idx]
    n = segments
    a = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]  # quad corners (u, v) in a flat grid
    quads = np.stack([a, a + n + 1, a + n + 2, a + 1], axis=-1).reshape(-1, 4)  # (u,v) (u+1,v) (u+1,v+1) (u,v+1)
    local = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])  # normal along ∂P/∂u × ∂P/∂v
    flat = [g.reshape(-1, 3) for g in grids]
    tris = np.concatenate([f[local] for f in flat])
    keep = [bool(o) for o in _outward(grids, tris)]
    pts = np.concatenate(flat)
    faces = np.concatenate([(local if k else local[:, ::-1]) + i * (n + 1) ** 2 for i, k in enumerate(keep)])
    # weld: points equal to 1e-9 data units become one vertex (first occurrence keeps its place)
    key = np.round(pts / 1e-9).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    faces = rank[inverse.reshape(-1)][faces]
    pts = pts[first[order]]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    s = height / (pts[:, 2].max() - pts[:, 2].min())
    scene = np.stack([pts[:, 0], pts[:, 2] - pts[:, 2].min(), -pts[:, 1]], axis=1) * s
    return scene.astype(np.float32), faces.astype(np.uint32)


def ply_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """A binary little-endian PLY file of float32 vertices (V, 3) and uint32 triangles (T, 3)."""
    head = ("ply\nformat binary_little_endian 1.0\ncomment Utah teapot (Newell's public-domain patches), "
            f"tessellated by scripts/make_teapot.py\nelement vertex {len(vertices)}\nproperty float x\n"
            f"property float y\nproperty float z\nelement face {len(faces)}\n"
            "property list uchar uint vertex_indices\nend_header\n").encode("ascii")
    v = np.ascontiguousarray(vertices, dtype="<f4").tobytes()
    f = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<u4", (3,))])
    f["n"], f["i"] = 3, faces
    return head + v + f.tobytes()


def main() -> None:
    v, f = mesh()
    OUT.write_bytes(ply_bytes(v, f))
    lo, hi = v.min(0), v.max(0)
    print(f"wrote {OUT}: {len(v)} vertices, {len(f)} triangles, size (x, y, z) = {np.round(hi - lo, 4)} m")


if __name__ == "__main__":
    main()
