"""Orchard scene: analytic primitives and their procedural textures.

World frame: z up, ground plane z = 0, tree rows run along +x. Rows sit at
``y = (j - 1) * row_spacing`` for ``j = 0 .. n_rows - 1``, so the driving
lanes between rows are at ``y = (k + 0.5) * row_spacing`` (lane 0 between
the first two rows at y = 0 and y = row_spacing... see ``lane_y``).

Primitives (all analytic, so depth is exact):
- ground plane z = 0 (grass and soil, tyre tracks along the lanes);
- trunks: vertical cylinders, bark texture (vertical grooves: line segments);
- canopies: one ellipsoid per tree (leaf texture: many ORB corners);
- posts: axis-aligned boxes at row ends and along the rows (straight edges),
  each end post carries white row tags with a black border on its faces,
  usable as exactly known image features (``OrchardScene.tags``);
- windbreak rows across both headlands so U-turns see structure.

Textures are procedural (band-limited noise built with numpy/OpenCV, no
external images) and stored as float32 "mip" stacks: the same texture
blurred by 2^k texels, picked per primitive (per pixel for the ground) from
the texel footprint, so distant surfaces do not alias into flickering noise.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# Texture scale: metres per texel.
GROUND_TEXEL = 0.01
BARK_TEXEL = 0.004
LEAF_TEXEL = 0.012
POST_TEXEL = 0.004
MIP_LEVELS = 6


@dataclass(frozen=True)
class Layout:
    """Scene layout numbers (a sub-set of ``SyntheticParams``)."""

    n_rows: int = 5
    row_spacing: float = 4.0
    row_length: float = 20.0
    tree_spacing: float = 1.6
    headland: float = 9.0  # distance of the windbreak rows beyond the row ends


@dataclass(frozen=True)
class Tag:
    """A square white marker with a black border on a post face."""

    center: np.ndarray  # (3,) world
    normal: np.ndarray  # (3,) unit, axis aligned
    size: float         # side of the white square (m)


def _periodic_noise(rng: np.random.Generator, shape: tuple[int, int], sigma: tuple[float, float]) -> np.ndarray:
    """Tileable Gaussian-filtered white noise, zero mean, unit std (FFT, exact wrap)."""
    h, w = shape
    white = rng.standard_normal(shape)
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.rfftfreq(w)[None, :]
    g = np.exp(-2.0 * np.pi**2 * ((fy * sigma[0]) ** 2 + (fx * sigma[1]) ** 2))
    out = np.fft.irfft2(np.fft.rfft2(white) * g, s=shape)
    out -= out.mean()
    return out / (out.std() + 1e-12)


def _periodic_blur(tex: np.ndarray, sigma: float) -> np.ndarray:
    if sigma <= 0:
        return tex
    h, w = tex.shape
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.rfftfreq(w)[None, :]
    g = np.exp(-2.0 * np.pi**2 * sigma**2 * (fy**2 + fx**2))
    return np.fft.irfft2(np.fft.rfft2(tex) * g, s=tex.shape)


def _mips(tex: np.ndarray) -> list[np.ndarray]:
    """Level k: the texture blurred by sigma = 0.5 * 2^k texels (same size, so same coordinates)."""
    return [np.ascontiguousarray(_periodic_blur(tex, 0.0 if k == 0 else 0.5 * 2**k), dtype=np.float32)
            for k in range(MIP_LEVELS)]


def _blobs(rng, tex: np.ndarray, n: int, rmin: float, rmax: float, vmin: float, vmax: float) -> None:
    """Scatter filled discs (leaves, pebbles) into ``tex`` in place, wrapping at the borders."""
    h, w = tex.shape
    for _ in range(n):
        x, y = rng.uniform(0, w), rng.uniform(0, h)
        r = rng.uniform(rmin, rmax)
        v = float(rng.uniform(vmin, vmax))
        for ox in (-w, 0, w):
            for oy in (-h, 0, h):
                cv2.circle(tex, (int(x + ox), int(y + oy)), int(r), v, -1, lineType=cv2.LINE_AA)


def make_textures(seed: int) -> dict[str, list[np.ndarray]]:
    """Procedural albedo textures in [0, 1] as mip stacks: ground, bark, leaf, post."""
    rng = np.random.default_rng([seed, 0x7E7])
    # Ground: grass of mixed scales, soil patches, pebbles and fallen leaves.
    n = 1024
    grass = 0.45 + 0.10 * _periodic_noise(rng, (n, n), (1.0, 1.0)) + 0.08 * _periodic_noise(rng, (n, n), (6.0, 6.0))
    soil = _periodic_noise(rng, (n, n), (40.0, 40.0))
    grass += 0.10 * np.tanh(2.0 * soil)
    grass = grass.astype(np.float32)
    _blobs(rng, grass, 500, 2, 6, 0.15, 0.85)
    ground = np.clip(grass, 0.02, 1.0)

    # Bark: wraps once around a trunk (u) and repeats every 2 m up (v);
    # long vertical grooves plus a few horizontal cracks.
    bh, bw = 512, 160
    grooves = _periodic_noise(rng, (bh, bw), (30.0, 1.2))
    fine = _periodic_noise(rng, (bh, bw), (1.0, 1.0))
    bark = 0.33 + 0.13 * np.tanh(1.5 * grooves) + 0.05 * fine
    cracks = _periodic_noise(rng, (bh, bw), (1.0, 12.0))
    bark -= 0.10 * (cracks > 1.8)
    bark = np.clip(bark, 0.02, 1.0).astype(np.float32)

    # Leaves: bright and dark leaf blobs over a dark interior (gaps).
    ln = 512
    leaf = (0.2 + 0.06 * _periodic_noise(rng, (ln, ln), (3.0, 3.0))).astype(np.float32)
    _blobs(rng, leaf, 5000, 1.5, 3.5, 0.25, 0.85)
    leaf = np.clip(leaf + 0.03 * _periodic_noise(rng, (ln, ln), (1.0, 1.0)).astype(np.float32), 0.02, 1.0)

    # Treated-pine post: fine vertical grain.
    ph, pw = 256, 64
    post = 0.55 + 0.06 * _periodic_noise(rng, (ph, pw), (25.0, 0.8)) + 0.03 * _periodic_noise(rng, (ph, pw), (1, 1))
    post = np.clip(post, 0.02, 1.0).astype(np.float32)
    return {"ground": _mips(ground), "bark": _mips(bark), "leaf": _mips(leaf), "post": _mips(post)}


class OrchardScene:
    """Primitive arrays of one orchard, built deterministically from ``seed``.

    Attributes (float64 arrays):
        trunk_xy (N, 2), trunk_r (N,), trunk_h (N,)
        canopy_c (N, 3), canopy_r (N, 2) = (horizontal, vertical) radii
        post_lo (M, 3), post_hi (M, 3): box corners
        tags: list of ``Tag``
        textures: ``make_textures(seed)``
        low_texture_x: tuple of (x0, x1) world-x ranges with washed-out texture
    """

    def __init__(self, layout: Layout = Layout(), seed: int = 0,
                 low_texture_x: tuple[tuple[float, float], ...] = ()):
        self.layout = layout
        self.low_texture_x = tuple(low_texture_x)
        rng = np.random.default_rng([seed, 0x5CE])
        L = layout.row_length
        xs, ys = [], []
        n_per_row = int(np.floor(L / layout.tree_spacing)) + 1
        for j in range(layout.n_rows):
            x = np.arange(n_per_row) * layout.tree_spacing
            x = x + rng.uniform(-0.15, 0.15, n_per_row)
            keep = rng.uniform(size=n_per_row) > 0.06  # a few missing trees, as in real rows
            keep[0] = keep[-1] = True
            xs.append(x[keep])
            ys.append(self.row_y(j) + rng.uniform(-0.08, 0.08, keep.sum()))
        # Windbreak rows across both headlands (denser, taller).
        span = np.arange(self.row_y(0) - 2.0, self.row_y(layout.n_rows - 1) + 2.0, 1.4)
        for xw in (-layout.headland, L + layout.headland):
            xs.append(xw + rng.uniform(-0.2, 0.2, span.size))
            ys.append(span + rng.uniform(-0.2, 0.2, span.size))
        x = np.concatenate(xs)
        y = np.concatenate(ys)
        n = x.size
        n_orchard = n - 2 * span.size
        windbreak = np.arange(n) >= n_orchard
        self.trunk_xy = np.stack([x, y], axis=1)
        self.trunk_r = np.where(windbreak, rng.uniform(0.12, 0.2, n), rng.uniform(0.07, 0.12, n))
        self.trunk_h = np.where(windbreak, rng.uniform(1.6, 2.2, n), rng.uniform(0.9, 1.25, n))
        ra = np.where(windbreak, rng.uniform(1.0, 1.4, n), rng.uniform(0.85, 1.15, n))
        rb = np.where(windbreak, rng.uniform(1.6, 2.2, n), rng.uniform(0.9, 1.25, n))
        cz = self.trunk_h + 0.75 * rb
        self.canopy_c = np.stack([x + rng.uniform(-0.1, 0.1, n), y + rng.uniform(-0.1, 0.1, n), cz], axis=1)
        self.canopy_r = np.stack([ra, rb], axis=1)

        # Posts: end posts of every orchard row (with tags) and trellis posts every ~4 trees.
        lo, hi, tags = [], [], []
        half, height, tag = 0.12, 2.0, 0.14
        for j in range(layout.n_rows):
            yr = self.row_y(j)
            for xe, outward in ((-0.9, -1.0), (L + 0.9, 1.0)):
                lo.append((xe - half, yr - half, 0.0))
                hi.append((xe + half, yr + half, height))
                # Tags on the two lane-facing faces and on the outward face, at 1.2 m.
                for normal in ((0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (outward, 0.0, 0.0)):
                    nrm = np.array(normal)
                    c = np.array([xe, yr, 1.2]) + half * nrm
                    tags.append(Tag(center=c, normal=nrm, size=tag))
            for xp in np.arange(4 * layout.tree_spacing, L - 1.0, 4 * layout.tree_spacing) + 0.5 * layout.tree_spacing:
                lo.append((xp - 0.04, yr - 0.04, 0.0))
                hi.append((xp + 0.04, yr + 0.04, 1.8))
        self.post_lo = np.array(lo, dtype=np.float64)
        self.post_hi = np.array(hi, dtype=np.float64)
        self.tags = tags
        self.tag_half = tag / 2
        self.tag_border = 0.2 * tag  # black frame; white + frame fit the 0.24 m face
        self.textures = make_textures(seed)

    def row_y(self, j: int) -> float:
        """World y of orchard row ``j`` (rows start one spacing below lane 0)."""
        return (j - 1) * self.layout.row_spacing

    def lane_y(self, k: int) -> float:
        """World y of driving lane ``k`` (between rows k and k + 1)."""
        return (k - 0.5) * self.layout.row_spacing

    @property
    def n_trees(self) -> int:
        return len(self.trunk_r)
