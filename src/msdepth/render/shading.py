"""Shading: procedural textures per material, sky and reflected environment, sun and highlights."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from msdepth.render.raycast import Camera
from msdepth.render.scene import (
    FOLIAGE,
    GLASS,
    METAL,
    PAINT,
    POLE,
    ROAD,
    SIGN,
    TYRE,
    WALL,
    Scene,
    fresnel_f0,
)

# A fixed tile of value noise, sampled with world/surface coordinates (plus a per-frame shift) so
# that both views see the same texture. Its own fixed seed keeps it independent of the frame RNG.
_TILE = np.random.default_rng(0x5EED).random((256, 256), dtype=np.float32)
_TILE_FLAT = _TILE.ravel()

# A material's pixels: attribute name -> one value per pixel (shade_view's _surface lists them).
_Surface = dict[str, np.ndarray]


@dataclass
class _Look:
    """What a shader gives its pixels; None = nothing of that kind."""

    albedo: np.ndarray | None = None  # lit by the sun and the ambient light
    extra: np.ndarray | None = None  # light not from Lambert: reflections, interiors
    spec_k: np.ndarray | float = 0.0  # weight of the sun's highlight
    shininess: np.ndarray | float = 1.0


def _noise(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Smooth value noise in [0, 1] with unit lattice spacing (tiles every 256 units)."""
    fu, fv = np.floor(u), np.floor(v)
    a, b = u - fu, v - fv
    a = a * a * (3 - 2 * a)
    b = b * b * (3 - 2 * b)
    iu, iv = fu.astype(np.int64) & 255, fv.astype(np.int64) & 255
    iu1, iv1 = (iu + 1) & 255, (iv + 1) & 255
    iv, iv1 = iv << 8, iv1 << 8
    top = _TILE_FLAT.take(iv + iu) * (1 - a) + _TILE_FLAT.take(iv + iu1) * a
    bottom = _TILE_FLAT.take(iv1 + iu) * (1 - a) + _TILE_FLAT.take(iv1 + iu1) * a
    return (top * (1 - b) + bottom * b).astype(np.float32, copy=False)


def _fbm(
    u: np.ndarray, v: np.ndarray, footprint: np.ndarray | float, freq: float, octaves: int = 3
) -> np.ndarray:
    """Fractal value noise (mean ~0.5) at ``freq`` cycles per unit, band-limited to the pixel footprint.

    Octaves finer than ~2 px fade to their mean so distant surfaces do not alias (aliasing would
    differ between the views and masquerade as a stereo error).
    """
    total = np.zeros_like(u, dtype=np.float32)
    amp, norm = 1.0, 0.0
    for k in range(octaves):
        fr = freq * 2**k
        weight = np.clip(2.0 - 4.0 * footprint * fr, 0.0, 1.0)
        total += amp * weight * (_noise(u * fr + 17.3 * k, v * fr - 31.7 * k) - 0.5)
        norm += amp
        amp *= 0.5
    return 0.5 + total / norm * 1.6


def _float32_of(ufunc: np.ufunc, *args: np.ndarray | float) -> np.ndarray:
    """``ufunc(*args)`` computed in float64 and rounded to float32.

    numpy's float32 ``power`` and ``arctan2`` have SIMD kernels (AVX2, AVX-512, none) that round
    differently: the same frame rendered on two CPUs differed by one level in a pixel of 51 of
    the default set's 4,015 files. The float64 kernels differ too, but by far less than a float32
    step, so rounded to float32 they agree (docs/design.md, "The synthetic set").
    """
    return ufunc(*(np.asarray(a, np.float64) for a in args)).astype(np.float32)


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of two (N, 3) arrays."""
    return np.einsum("ij,ij->i", a, b)


def _frac(x: np.ndarray) -> np.ndarray:
    return x - np.floor(x)


def _sky(scene: Scene, d: np.ndarray) -> np.ndarray:
    """Sky colour along unit directions ``d``: horizon-to-zenith gradient with clouds."""
    e = -d[:, 1]
    t = _float32_of(np.power, np.clip(e / 0.6, 0, 1), 0.6)[:, None]
    col = scene.sky_horizon * (1 - t) + scene.sky_zenith * t
    s = 1.0 / (np.maximum(e, 0.02) + 0.1)
    c = _fbm(d[:, 0] * s * 2 + scene.tex_shift[0], d[:, 2] * s * 2 + scene.tex_shift[1], 0.0, 1.0, 4)
    cover = np.clip((c - (1.05 - scene.cloud_cover * 0.6)) * 4, 0, 1)[:, None]
    return (col * (1 - cover) + np.float32(0.92) * cover).astype(np.float32)


def _environment(scene: Scene, d: np.ndarray) -> np.ndarray:
    """What a mirror reflects along unit directions ``d``: sky, a skyline with windows, the street."""
    e = -d[:, 1]
    az = _float32_of(np.arctan2, d[:, 0], d[:, 2])
    col = _sky(scene, d)
    # Overhead: branches, wires and cloud edges as fine, high-contrast patches. A reflection's
    # content then shifts visibly between the two viewpoints (it lies at another depth).
    s = 1.0 / (np.maximum(e, 0.0) + 0.3)
    over = _fbm(d[:, 0] * s + scene.tex_shift[1], d[:, 2] * s, 0.0, 40.0, 3)
    dark = np.clip((over - 0.5) * 4, 0, 1)[:, None] * np.float32(scene.canopy)
    col = col * (1 - dark) + np.float32(0.12) * dark
    skyline = 0.05 + 0.35 * _noise(az * 4 + scene.tex_shift[0], np.full_like(az, 3.5))
    bld = (e >= 0) & (e < skyline)
    if bld.any():
        a, el = az[bld], e[bld]
        tone = 0.25 + 0.5 * _noise(np.floor(a * 10) * 7.1, np.full_like(a, 1.5))
        win = (_frac(a * 70) < 0.45) & (_frac(el * 45) < 0.5)
        shade = np.where(win, 0.08 + 0.9 * (_noise(a * 70, el * 45) > 0.7), tone)
        col[bld] = shade[:, None] * np.array([1.0, 0.97, 0.92], np.float32)
    ground = e < 0
    if ground.any():
        col[ground] = (0.22 + 0.15 * _noise(az[ground] * 30, e[ground] * 30))[:, None]
    return col


def _shade_road(scene: Scene, h: _Surface) -> _Look:
    """Asphalt with lane markings, paved sidewalks, grass beyond open sides."""
    r = scene.road
    x, z, fp = h["P"][:, 0], h["P"][:, 2], h["fp"]
    sx, sz = x + scene.tex_shift[0], z + scene.tex_shift[1]
    grain = _fbm(sx, sz, fp, 4.0, 3)
    patches = _fbm(sx * 0.7, sz, fp, 0.35, 3)  # repairs, stains, tyre tracks: survive distance
    col = (r["asphalt"] * (0.45 + 0.5 * grain + 0.5 * patches))[:, None] * np.ones(3, np.float32)
    lw = r["line_width"]
    dashed = _frac((z + r["phase"]) / r["period"]) < r["dash"] / r["period"]
    mark = np.zeros(x.shape, bool)
    for xl in r["lines"]:
        mark |= (np.abs(x - xl) < lw / 2) & dashed
    for edge in (r["left"] + 0.3, r["right"] - 0.3):
        mark |= np.abs(x - edge) < lw / 2
    col[mark] = (0.8 + 0.1 * grain[mark])[:, None]
    walk = (x < r["left"]) | (x > r["right"])
    if walk.any():
        tiles = (_frac(sx[walk] / 0.4) < 0.06) | (_frac(sz[walk] / 0.4) < 0.06)
        # Joints only where resolved; further away they average into a slightly darker tone.
        joint = np.where(fp[walk] < 0.02, np.where(tiles, 0.7, 1.0), 0.96)
        shade = (0.8 + 0.35 * (grain[walk] - 0.5) + 0.3 * (patches[walk] - 0.5)) * joint
        col[walk] = shade[:, None] * r["pave"]
        kerb = walk & ((np.abs(x - r["left"]) < 0.15) | (np.abs(x - r["right"]) < 0.15))
        col[kerb] = 0.75
    grass = (x < r["grass_left"]) | (x > r["grass_right"])
    if grass.any():
        g = _fbm(sx[grass] * 1.3, sz[grass], fp[grass], 3.0, 3)
        col[grass] = (0.4 + 0.9 * g)[:, None] * np.array([0.2, 0.38, 0.1], np.float32)
    return _Look(col)


def _shade_wall(scene: Scene, h: _Surface) -> _Look:
    """Plaster or brick with a grid of windows above the ground floor."""
    u, v, fp, prm, col = h["u"], h["v"], h["fp"], h["prm"], h["col"]
    su, sv = h["su"], h["sv"]
    tone = 0.8 + 0.4 * (_fbm(su, sv, fp, 1.5, 3) - 0.5) + 0.25 * (_fbm(su, sv, fp, 12.0, 2) - 0.5)
    # Bricks only where a pixel resolves them (mortar lines would alias differently per view).
    brick = (prm[:, 4] > 0.5) & (fp < 0.03)
    if brick.any():
        row = np.floor(sv[brick] / 0.075)
        bu = su[brick] / 0.24 + 0.5 * (row % 2)
        mortar = (_frac(sv[brick] / 0.075) < 0.15) | (_frac(bu) < 0.06)
        per_brick = 0.75 + 0.5 * _noise(np.floor(bu) * 3.1, row * 1.7)
        tone[brick] = np.where(mortar, 1.35, per_brick)
    albedo = tone[:, None] * col
    fu, fv = _frac(u / prm[:, 0]), _frac(v / prm[:, 1])
    win = (
        (fu > 0.5 - prm[:, 2] / 2)
        & (fu < 0.5 + prm[:, 2] / 2)
        & (fv > 0.5 - prm[:, 3] / 2)
        & (fv < 0.5 + prm[:, 3] / 2)
        & (v > prm[:, 5])
        & (v < prm[:, 6] - 1.0)
    )
    if win.any():
        lit = _noise(np.floor(u[win] / prm[win, 0]) * 5.3, np.floor(v[win] / prm[win, 1]) * 2.9)
        albedo[win] = h["col2"][win] * (0.6 + 1.2 * lit)[:, None]
    return _Look(albedo, spec_k=0.15, shininess=40)


def _shade_foliage(scene: Scene, h: _Surface) -> _Look:
    leaves = _fbm(h["su"], h["sv"], h["fp"], 5.0, 3) * 0.6 + _fbm(h["su"], h["sv"], h["fp"], 0.7, 2) * 0.6
    return _Look((0.2 + leaves)[:, None] * h["col"])


def _shade_paint(scene: Scene, h: _Surface) -> _Look:
    """Car paint with tail/head lights and a number plate on the front and back faces, clear coat."""
    albedo = h["col"] * (0.92 + 0.16 * _fbm(h["su"], h["sv"], h["fp"], 3.0, 2))[:, None]
    u, v, kind = h["u"], h["v"], h["prm"][:, 0]
    ends = kind > 0.5
    if ends.any():
        au = np.abs(u[ends])
        lights = (v[ends] > 0.65) & (v[ends] < 0.82) & (au > 0.45) & (au < h["prm"][ends, 1] - 0.05)
        plate = (au < 0.26) & (v[ends] > 0.36) & (v[ends] < 0.47)
        lamp = np.where(
            (kind[ends] > 1.5)[:, None],
            np.array([0.7, 0.05, 0.04], np.float32),
            np.array([0.9, 0.9, 0.85], np.float32),
        )
        sub = albedo[ends]
        sub[lights] = lamp[lights]
        sub[plate] = 0.85
        albedo[ends] = sub
    fres, env = _reflection(scene, h, 0.04)  # clear coat: a faint reflection
    return _Look(albedo, 0.3 * fres[:, None] * env, spec_k=0.8, shininess=60)


def _shade_sign(scene: Scene, h: _Surface) -> _Look:
    """Pictograms on the plate's front: prohibition ring, arrow, hazard stripes, direction text."""
    prm = h["prm"]
    a, b = h["u"] / prm[:, 1] + 0.5, h["v"] / prm[:, 2] + 0.5
    kind = prm[:, 0].astype(int)
    r = np.hypot(a - 0.5, b - 0.5)
    out = np.empty(a.shape + (3,), np.float32)
    white, red, blue = np.array([0.92, 0.92, 0.9]), np.array([0.8, 0.08, 0.06]), np.array([0.05, 0.2, 0.65])
    yellow, black, green = (
        np.array([0.95, 0.75, 0.05]),
        np.array([0.05, 0.05, 0.05]),
        np.array([0.05, 0.45, 0.2]),
    )
    k0 = kind == 0
    out[k0] = np.where(((r[k0] > 0.33) & (r[k0] < 0.47))[:, None], red, white)
    bars = k0 & (np.abs(a - 0.5) < 0.15) & (np.abs(b - 0.5) < 0.18) & (_frac(a * 7) < 0.5)
    out[bars] = black
    k1 = kind == 1
    arrow = (b > 0.2) & (b < 0.8) & (np.abs(a - 0.5) < 0.35 * (b - 0.2) / 0.6 + 0.05)
    out[k1] = np.where(arrow[k1][:, None], white, blue)
    k2 = kind == 2
    out[k2] = np.where((_frac((a + b) * 4)[k2] < 0.5)[:, None], yellow, black)
    k3 = kind == 3
    text = (_frac(b * 5) < 0.35) & (np.abs(a - 0.5) < 0.38) & (_frac(a * 9 + b * 3) < 0.7)
    out[k3] = np.where(text[k3][:, None], white, green)
    fres, env = _reflection(scene, h, 0.2)  # glossy, partly retro-reflective film
    return _Look(out, prm[:, 3:4] * fres[:, None] * env, spec_k=1.5 * prm[:, 3], shininess=20)


def _shade_glass(scene: Scene, h: _Surface) -> _Look:
    """Tinted glass: a dark interior behind it, mixed (Fresnel) with the reflected environment.

    ``prm[0]`` is the pane's index of refraction; Schlick's F0 is the dielectric's (~0.04).
    """
    fres, env = _reflection(scene, h, fresnel_f0(h["prm"][:, 0]))
    # The interior sits behind the glass: sample it further along the ray.
    q = h["P"] + h["d"] * h["prm"][:, 1:2]
    inside = _fbm(q[:, 0] * 1.7 + q[:, 1] * 1.1, q[:, 2] * 1.7 - q[:, 1] * 0.9, h["fp"], 1.5, 3)
    interior = h["col"] * (0.4 + 1.6 * inside)[:, None] * np.float32(scene.ambient * 2.5)
    return _Look(extra=(1 - fres)[:, None] * interior + fres[:, None] * env, spec_k=6.0, shininess=400)


def _shade_tyre(scene: Scene, h: _Surface) -> _Look:
    return _Look(h["col"] * (0.8 + 0.4 * _fbm(h["su"], h["sv"], h["fp"], 8.0, 2))[:, None])


def _shade_metal(scene: Scene, h: _Surface) -> _Look:
    """Poles and the backs of sign plates."""
    albedo = h["col"] * (0.85 + 0.3 * _fbm(h["su"], h["sv"], h["fp"], 6.0, 2))[:, None]
    return _Look(albedo, spec_k=0.5, shininess=30)


# Each material's shader: its pixels' surface attributes -> their look.
SHADERS: dict[int, Callable[[Scene, _Surface], _Look]] = {
    ROAD: _shade_road,
    WALL: _shade_wall,
    FOLIAGE: _shade_foliage,
    PAINT: _shade_paint,
    GLASS: _shade_glass,
    TYRE: _shade_tyre,
    POLE: _shade_metal,
    METAL: _shade_metal,
    SIGN: _shade_sign,
}


def shade_view(
    scene: Scene, cam: Camera, origin: np.ndarray, depth: np.ndarray, face: np.ndarray
) -> np.ndarray:
    """Colour (float RGB, ~[0, 1]) of every pixel of one view."""
    out = np.empty((cam.height * cam.width, 3), np.float32)
    fid = face.ravel()
    sky = fid < 0
    if sky.any():
        out[sky] = _sky(scene, cam.unit.reshape(-1, 3)[sky])
    idx = np.nonzero(~sky)[0]
    if not idx.size:
        return out.reshape(cam.height, cam.width, 3)
    # Hit pixels sorted by material: each material's pixels are then a slice (a view, no copy).
    mat = scene.arrays["mat"].take(fid[idx])
    idx = np.concatenate([idx[mat == m] for m in range(mat.max() + 1)])  # counting sort
    h = _surface(scene, cam, origin, depth.ravel()[idx], fid[idx], idx)
    out[idx] = _light(scene, h, *_looks(scene, h, scene.arrays["mat"].take(fid[idx])))
    return out.reshape(cam.height, cam.width, 3)


def _surface(
    scene: Scene, cam: Camera, origin: np.ndarray, t: np.ndarray, f: np.ndarray, idx: np.ndarray
) -> _Surface:
    """The attributes shaders read at hit pixels ``idx`` (ray length ``t``, face ids ``f``)."""
    A = scene.arrays
    d = cam.unit.reshape(-1, 3).take(idx, axis=0)
    P = origin.astype(np.float32) + cam.dirs.reshape(-1, 3).take(idx, axis=0) * t[:, None]

    def gather(key: str) -> np.ndarray:
        return A[key].take(f, axis=0)

    n = gather("normal")
    n_dot_v = -_rowdot(n, d)
    rel = P - gather("org")
    h = dict(
        P=P,
        d=d,
        n=n,
        n_dot_v=n_dot_v,
        u=_rowdot(rel, gather("uax")),
        v=_rowdot(rel, gather("vax")),
        col=gather("col"),
        col2=gather("col2"),
        prm=gather("prm"),
        # Metres of surface per pixel, the band limit of every texture: the geometric mean of
        # the footprint across (t/f) and along (t/f/cos) the view, so that a road seen at a
        # grazing angle keeps some texture instead of fading to flat grey.
        fp=t / np.float32(cam.f) / np.sqrt(np.maximum(np.abs(n_dot_v), np.float32(0.05))),
    )
    # Noise coordinates carry the per-frame shift; pattern coordinates (u, v) stay put.
    h["su"], h["sv"] = h["u"] + scene.tex_shift[0], h["v"] + scene.tex_shift[1]
    return h


def _reflection(scene: Scene, h: _Surface, f0: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Schlick-Fresnel weight and the environment along the mirrored view ray."""
    cos = np.clip(h["n_dot_v"], 0, 1)
    fres = f0 + (1 - f0) * _float32_of(np.power, 1 - cos, 5)
    mirrored = h["d"] + 2 * cos[:, None] * h["n"]
    return fres.astype(np.float32), _environment(scene, mirrored)


def _looks(
    scene: Scene, h: _Surface, mat: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Albedo, extra light, specular weight and shininess of every pixel of ``h`` (sorted by
    material ``mat``), each material's slice from its shader in :data:`SHADERS`."""
    albedo = np.zeros((mat.size, 3), np.float32)
    extra = np.zeros((mat.size, 3), np.float32)
    spec_k = np.zeros(mat.size, np.float32)
    shininess = np.ones(mat.size, np.float32)
    bounds = np.searchsorted(mat, np.arange(mat[-1] + 2))
    for m in np.unique(mat):
        sel = slice(bounds[m], bounds[m + 1])
        look = SHADERS[m](scene, {k: a[sel] for k, a in h.items()})
        if look.albedo is not None:
            albedo[sel] = look.albedo
        if look.extra is not None:
            extra[sel] = look.extra
        spec_k[sel], shininess[sel] = look.spec_k, look.shininess
    return albedo, extra, spec_k, shininess


def _light(
    scene: Scene,
    h: _Surface,
    albedo: np.ndarray,
    extra: np.ndarray,
    spec_k: np.ndarray,
    shininess: np.ndarray,
) -> np.ndarray:
    """Sun and ambient light on the albedo, the sun's highlight, plus the extra light."""
    n, d = h["n"], h["d"]
    n_dot_l = np.clip(n @ scene.sun.astype(np.float32), 0, None)
    half = scene.sun.astype(np.float32) - d
    half /= np.sqrt(_rowdot(half, half))[:, None]
    n_dot_h = np.clip(_rowdot(n, half), 0, None)
    # The highlight only where it can matter (0.6 ** 20 is already ~4e-5): pow is slow.
    lit = np.nonzero((spec_k > 0) & (n_dot_h > 0.6) & (n_dot_l > 0))[0]
    spec = np.zeros_like(spec_k)
    spec[lit] = spec_k[lit] * _float32_of(np.power, n_dot_h[lit], shininess[lit])
    light = (scene.ambient + n_dot_l)[:, None] * scene.sun_colour.astype(np.float32)
    return albedo * light + spec[:, None] * scene.sun_colour.astype(np.float32) + extra
