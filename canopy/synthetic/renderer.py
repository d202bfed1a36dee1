"""Vectorised ray caster for the orchard scene.

Every pixel's ray is intersected analytically with the primitives; a
z-buffer keeps the nearest hit. Rays are built with camera-frame z = 1, so
the ray parameter of a hit *is* its depth (camera z), exact up to float32.

Cost control (the ≥ 10 stereo frames/s target at 752×480 on two cores):
- ground and sky are computed for the whole image (a handful of float32 ops);
- each trunk, canopy and post is intersected only inside the image rectangle
  its bounding box projects to, and only if within ``max_range``;
- textures are sampled with ``cv2.remap`` (bilinear, wrapping), one mip level
  per primitive from its distance, per pixel (two levels blended) for ground.
The only Python loop is over the primitives in range (tens per frame).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from shared.types import StereoCalibration

from .scene import BARK_TEXEL, GROUND_TEXEL, LEAF_TEXEL, MIP_LEVELS, POST_TEXEL, OrchardScene

NEAR = 0.05  # metres: hits closer than this are ignored (inside a primitive)

# Surface labels in the label image.
SKY, GROUND, TRUNK, CANOPY, POST, TAG = 0, 1, 2, 3, 4, 5

SUN = np.array([0.45, -0.35, 0.82])
SUN = SUN / np.linalg.norm(SUN)
AMBIENT = 0.55
DIFFUSE = 0.55
TAG_WHITE, TAG_BLACK = 0.97, 0.04


@dataclass
class RenderOutput:
    """Noise-free radiance in [0, ~1] (float32), depth (float32 metres, inf = sky),
    label (uint8, see SKY..TAG) and world hit x/y (float32, for conditions)."""

    radiance: np.ndarray
    depth: np.ndarray
    label: np.ndarray
    world_x: np.ndarray
    world_y: np.ndarray


def _sample(tex: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear, wrapping texture lookup at texel coordinates (u: column, v: row)."""
    h, w = tex.shape
    # Wrap into one period first (remap's fixed-point maps overflow beyond ~32k texels);
    # floor-based wrapping is ~40x faster than np.mod on float32.
    u = fast_mod(u, w)
    v = fast_mod(v, h)
    return cv2.remap(tex, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)


def fast_mod(x: np.ndarray, period: float) -> np.ndarray:
    """``x mod period`` in [0, period) for float32 arrays (np.mod is ~40x slower)."""
    p = np.float32(period)
    return x - np.floor(x * (np.float32(1.0) / p)) * p


def _tight(m: np.ndarray) -> tuple[slice, slice] | None:
    """Bounding slices of the True pixels of ``m`` (None if there are none)."""
    rows = np.flatnonzero(m.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(m[rows[0]:rows[-1] + 1].any(axis=0))
    return slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1)


def _mip_level(distance: float, texel: float, fx: float) -> int:
    """Mip level whose blur matches one pixel's footprint at ``distance``."""
    footprint = distance / fx / texel  # texels per pixel
    return int(np.clip(np.floor(np.log2(max(footprint, 1.0))), 0, MIP_LEVELS - 1))


class Renderer:
    """Renders one pinhole camera (the rectified left or right camera) of ``scene``."""

    def __init__(self, scene: OrchardScene, calibration: StereoCalibration, max_range: float = 45.0):
        self.scene = scene
        self.cal = calibration
        self.max_range = float(max_range)
        c = calibration
        u = (np.arange(c.width, dtype=np.float64) - c.cx) / c.fx
        v = (np.arange(c.height, dtype=np.float64) - c.cy) / c.fy
        self._ru = np.broadcast_to(u[None, :], (c.height, c.width)).astype(np.float32)
        self._rv = np.broadcast_to(v[:, None], (c.height, c.width)).astype(np.float32)
        s = scene
        # Bounding boxes of every primitive, (P, 2, 3) lo/hi, and kinds.
        trunk_lo = np.c_[s.trunk_xy - s.trunk_r[:, None], np.zeros(s.n_trees)]
        trunk_hi = np.c_[s.trunk_xy + s.trunk_r[:, None], s.trunk_h]
        ra, rb = s.canopy_r[:, 0:1], s.canopy_r[:, 1:2]
        can_lo = s.canopy_c - np.c_[ra, ra, rb]
        can_hi = s.canopy_c + np.c_[ra, ra, rb]
        self._box_lo = np.concatenate([trunk_lo, can_lo, s.post_lo])
        self._box_hi = np.concatenate([trunk_hi, can_hi, s.post_hi])
        n, m = s.n_trees, len(s.post_lo)
        self._kind = np.r_[np.full(n, TRUNK), np.full(n, CANOPY), np.full(m, POST)]
        self._index = np.r_[np.arange(n), np.arange(n), np.arange(m)]
        self._centre = 0.5 * (self._box_lo + self._box_hi)
        corners = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)
        self._corner_sel = corners  # (8, 3) choose lo (0) or hi (1)
        # Tags grouped by post (post index -> list of tags) for the post shader.
        self._post_tags: dict[int, list] = {}
        for tag in s.tags:
            inside = np.all((tag.center >= s.post_lo - 1e-6) & (tag.center <= s.post_hi + 1e-6), axis=1)
            self._post_tags.setdefault(int(np.argmax(inside)), []).append(tag)

    # ------------------------------------------------------------------
    def render(self, T_world_cam: np.ndarray) -> RenderOutput:
        c = self.cal
        H, W = c.height, c.width
        R = np.asarray(T_world_cam, dtype=np.float64)[:3, :3]
        o = np.asarray(T_world_cam, dtype=np.float64)[:3, 3]
        Rf = R.astype(np.float32)
        # World ray directions (camera z component = 1, so ray parameter = depth).
        d = [Rf[i, 0] * self._ru + Rf[i, 1] * self._rv + Rf[i, 2] for i in range(3)]
        dx, dy, dz = d

        depth = np.full((H, W), np.inf, dtype=np.float32)
        label = np.zeros((H, W), dtype=np.uint8)
        radiance = self._sky(dz)
        # Ground plane z = 0, computed only in the rows that see it (below the horizon).
        grows = np.flatnonzero((dz < 0).any(axis=1))
        if grows.size:
            gs = slice(grows[0], grows[-1] + 1)
            dzg = dz[gs]
            ground = dzg < 0
            with np.errstate(divide="ignore", invalid="ignore"):
                tg = np.where(ground, np.float32(-o[2]) / dzg, np.float32(0.0))
            gx = np.float32(o[0]) + tg * dx[gs]
            gy = np.float32(o[1]) + tg * dy[gs]
            depth[gs] = np.where(ground, tg, np.float32(np.inf))
            label[gs][ground] = GROUND
            radiance[gs] = np.where(ground, self._ground_shade(gx, gy, tg, float(o[2])), radiance[gs])

        # Primitives in range, nearest first (fewer shaded pixels later lose the z-test).
        dist = np.linalg.norm(self._centre[:, :2] - o[:2], axis=1)
        R_cw = R.T
        for p in np.argsort(dist):
            if dist[p] > self.max_range:
                break
            rect = self._project_box(p, R_cw, o)
            if rect is None:
                continue
            r0, r1, c0, c1 = rect
            sl = (slice(r0, r1), slice(c0, c1))
            kind, i = self._kind[p], self._index[p]
            if kind == TRUNK:
                self._trunk(i, o, dx[sl], dy[sl], dz[sl], depth[sl], radiance[sl], label[sl], dist[p])
            elif kind == CANOPY:
                self._canopy(i, o, dx[sl], dy[sl], dz[sl], depth[sl], radiance[sl], label[sl], dist[p])
            else:
                self._post(i, o, dx[sl], dy[sl], dz[sl], depth[sl], radiance[sl], label[sl], dist[p])

        hit = label != SKY
        wx = np.where(hit, np.float32(o[0]) + depth * dx, np.float32(np.nan))
        wy = np.where(hit, np.float32(o[1]) + depth * dy, np.float32(np.nan))
        return RenderOutput(radiance=radiance, depth=depth, label=label, world_x=wx, world_y=wy)

    # ------------------------------------------------------------------
    def _project_box(self, p: int, R_cw: np.ndarray, o: np.ndarray):
        """Pixel rectangle (r0, r1, c0, c1) covering primitive ``p``'s box, or None if not visible."""
        lo, hi = self._box_lo[p], self._box_hi[p]
        pts = lo + self._corner_sel * (hi - lo)
        pc = (pts - o) @ R_cw.T
        z = pc[:, 2]
        c = self.cal
        if z.max() < NEAR:
            return None
        if z.min() < NEAR:  # straddles the camera plane: take the whole image
            return 0, c.height, 0, c.width
        u = c.fx * pc[:, 0] / z + c.cx
        v = c.fy * pc[:, 1] / z + c.cy
        c0 = max(int(np.floor(u.min())) - 1, 0)
        c1 = min(int(np.ceil(u.max())) + 2, c.width)
        r0 = max(int(np.floor(v.min())) - 1, 0)
        r1 = min(int(np.ceil(v.max())) + 2, c.height)
        if c0 >= c1 or r0 >= r1:
            return None
        return r0, r1, c0, c1

    def _sky(self, dz: np.ndarray) -> np.ndarray:
        # Brighter towards the zenith; dz is not normalised but its sign and trend suffice.
        return np.float32(0.82) + np.float32(0.12) * np.clip(dz, -1, 1)

    def _ground_shade(self, gx: np.ndarray, gy: np.ndarray, depth: np.ndarray, cam_height: float) -> np.ndarray:
        mips = self.scene.textures["ground"]
        u = gx / np.float32(GROUND_TEXEL)
        v = gy / np.float32(GROUND_TEXEL)
        # Footprint along the viewing direction grows like depth^2 / (f h): use the
        # geometric mean with the lateral footprint depth / f.
        h = max(abs(cam_height), 0.3)
        # log2 footprint = 1.5 log2(depth) - log2(sqrt(h) fx texel)
        with np.errstate(divide="ignore", invalid="ignore"):
            lev = np.float32(1.5) * np.log2(np.maximum(depth, np.float32(1e-3))) - np.float32(
                np.log2(np.sqrt(h) * self.cal.fx * GROUND_TEXEL))
        lev = np.clip(lev, 0, MIP_LEVELS - 1.001)
        k = lev.astype(np.int32)
        frac = lev - k
        out = np.empty_like(depth)
        kmin, kmax = k.min(axis=1), k.max(axis=1)
        for lvl in range(MIP_LEVELS - 1):
            rows = np.flatnonzero((kmin <= lvl) & (kmax >= lvl))
            if rows.size == 0:
                continue
            sl = slice(rows[0], rows[-1] + 1)
            a = _sample(mips[lvl], u[sl], v[sl])
            b = _sample(mips[lvl + 1], u[sl], v[sl])
            blend = a + (b - a) * frac[sl]
            out[sl] = blend if kmin[sl].min() == kmax[sl].max() == lvl else np.where(k[sl] == lvl, blend, out[sl])
        # Tyre tracks: two darker, smoother strips along every lane (straight lines for LSD).
        rs = np.float32(self.scene.layout.row_spacing)
        ly = fast_mod(gy + rs / 2, rs) - rs / 2  # y relative to the nearest lane centre
        track = (np.abs(np.abs(ly) - np.float32(0.7)) < np.float32(0.13)) & (gx > -1.5) & (
            gx < self.scene.layout.row_length + 1.5)
        out = np.where(track, np.float32(0.55) * out + np.float32(0.12), out)
        return out * np.float32(AMBIENT + DIFFUSE * SUN[2])

    # -- primitives: write into the sub-rectangle views in place ---------------
    def _trunk(self, i, o, dx, dy, dz, depth, rad, lab, dist):
        s = self.scene
        a, b = s.trunk_xy[i]
        r = s.trunk_r[i]
        ox, oy = np.float32(o[0] - a), np.float32(o[1] - b)
        A = dx * dx + dy * dy
        B = dx * ox + dy * oy
        C = np.float32(ox * ox + oy * oy - r * r)
        disc = B * B - A * C
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (-B - np.sqrt(disc)) / A
        z = np.float32(o[2]) + t * dz
        m = (disc > 0) & (t > NEAR) & (t < depth) & (z >= 0) & (z <= np.float32(s.trunk_h[i]))
        sl = _tight(m)
        if sl is None:
            return
        t, z, dx, dy, m, depth, rad, lab = t[sl], z[sl], dx[sl], dy[sl], m[sl], depth[sl], rad[sl], lab[sl]
        hx = ox + t * dx
        hy = oy + t * dy
        tex = s.textures["bark"]
        lvl = _mip_level(dist, BARK_TEXEL, self.cal.fx)
        th, tw = tex[0].shape
        ang = np.arctan2(hy, hx)
        u = (ang * np.float32(tw / (2 * np.pi)))
        v = z * np.float32(1.0 / BARK_TEXEL) + np.float32(i * 37.0)
        alb = _sample(tex[lvl], u, v)
        ndot = (hx * np.float32(SUN[0]) + hy * np.float32(SUN[1])) / np.float32(r)
        shade = np.float32(AMBIENT * 0.8) + np.float32(DIFFUSE) * np.maximum(ndot, 0)
        np.copyto(depth, t, where=m)
        np.copyto(rad, alb * shade, where=m)
        lab[m] = TRUNK

    def _canopy(self, i, o, dx, dy, dz, depth, rad, lab, dist):
        s = self.scene
        cx, cy, cz = s.canopy_c[i]
        ra, rb = s.canopy_r[i]
        ia, ib = np.float32(1.0 / ra), np.float32(1.0 / rb)
        ox, oy, oz = np.float32((o[0] - cx) / ra), np.float32((o[1] - cy) / ra), np.float32((o[2] - cz) / rb)
        ex, ey, ez = dx * ia, dy * ia, dz * ib
        A = ex * ex + ey * ey + ez * ez
        B = ex * ox + ey * oy + ez * oz
        C = np.float32(ox * ox + oy * oy + oz * oz - 1.0)
        disc = B * B - A * C
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (-B - np.sqrt(disc)) / A
        m = (disc > 0) & (t > NEAR) & (t < depth)
        sl = _tight(m)
        if sl is None:
            return
        t, ex, ey, ez, m, depth, rad, lab = t[sl], ex[sl], ey[sl], ez[sl], m[sl], depth[sl], rad[sl], lab[sl]
        nx, ny, nz = ox + t * ex, oy + t * ey, oz + t * ez  # unit-sphere point
        tex = s.textures["leaf"]
        lvl = _mip_level(dist, LEAF_TEXEL, self.cal.fx)
        ang = np.arctan2(ny, nx)
        u = ang * np.float32(ra / LEAF_TEXEL) + np.float32(i * 53.0)
        v = np.arcsin(np.clip(nz, -1, 1)) * np.float32(rb / LEAF_TEXEL)
        alb = _sample(tex[lvl], u, v)
        ndot = nx * np.float32(SUN[0]) + ny * np.float32(SUN[1]) + nz * np.float32(SUN[2])
        # Self-shadowed underside: darker towards the bottom of the crown.
        shade = np.float32(0.45) + np.float32(0.22) * nz + np.float32(0.45) * np.maximum(ndot, 0)
        np.copyto(depth, t, where=m)
        np.copyto(rad, alb * shade, where=m)
        lab[m] = CANOPY

    def _post(self, i, o, dx, dy, dz, depth, rad, lab, dist):
        s = self.scene
        lo = s.post_lo[i] - o
        hi = s.post_hi[i] - o
        with np.errstate(invalid="ignore", divide="ignore"):
            tmin = None
            tmax = None
            axis = None
            for k, dk in enumerate((dx, dy, dz)):
                inv = np.float32(1.0) / dk
                t1 = np.float32(lo[k]) * inv
                t2 = np.float32(hi[k]) * inv
                tn, tf = np.minimum(t1, t2), np.maximum(t1, t2)
                if tmin is None:
                    tmin, tmax, axis = tn, tf, np.zeros(tn.shape, np.uint8)
                else:
                    bigger = tn > tmin
                    axis = np.where(bigger, np.uint8(k), axis)
                    tmin = np.maximum(tmin, tn)
                    tmax = np.minimum(tmax, tf)
        m = (tmin <= tmax) & (tmin > NEAR) & (tmin < depth)
        sl = _tight(m)
        if sl is None:
            return
        t, axis, dx, dy, dz, m = tmin[sl], axis[sl], dx[sl], dy[sl], dz[sl], m[sl]
        depth, rad, lab = depth[sl], rad[sl], lab[sl]
        hx = np.float32(o[0]) + t * dx
        hy = np.float32(o[1]) + t * dy
        hz = np.float32(o[2]) + t * dz
        # Face normals: sign opposite to the ray along the hit axis.
        u = np.where(axis == 0, hy, hx) * np.float32(1.0 / POST_TEXEL)
        tex = s.textures["post"]
        lvl = _mip_level(dist, POST_TEXEL, self.cal.fx)
        alb = _sample(tex[lvl], u, hz * np.float32(1.0 / POST_TEXEL))
        nsx = np.where(axis == 0, -np.sign(dx), 0).astype(np.float32)
        nsy = np.where(axis == 1, -np.sign(dy), 0).astype(np.float32)
        nsz = np.where(axis == 2, -np.sign(dz), 0).astype(np.float32)
        ndot = nsx * np.float32(SUN[0]) + nsy * np.float32(SUN[1]) + nsz * np.float32(SUN[2])
        shade = np.float32(AMBIENT * 0.75) + np.float32(DIFFUSE) * np.maximum(ndot, 0)
        value = alb * shade
        is_tag = np.zeros(m.shape, bool)
        for tag in self._post_tags.get(int(i), ()):
            k = int(np.argmax(np.abs(tag.normal)))
            facing = (axis == k) & (np.sign(tag.normal[k]) == -np.sign((dx, dy, dz)[k]))
            lateral = hy if k == 0 else hx
            du = np.abs(lateral - np.float32(tag.center[1 if k == 0 else 0]))
            dv = np.abs(hz - np.float32(tag.center[2]))
            half = np.float32(s.tag_half)
            outer = facing & (du < half + np.float32(s.tag_border)) & (dv < half + np.float32(s.tag_border))
            inner = outer & (du < half) & (dv < half)
            value = np.where(outer, np.float32(TAG_BLACK), value)
            value = np.where(inner, np.float32(TAG_WHITE), value)
            is_tag |= inner
        np.copyto(depth, t, where=m)
        np.copyto(rad, value, where=m)
        lab[m] = POST
        lab[m & is_tag] = TAG
