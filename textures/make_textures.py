"""Regenerate the terrain textures, ``index.yaml`` and ``contact_sheet.png`` in this folder.

    python textures/make_textures.py [--out DIR]

Deterministic: fixed seeds, no time stamps, so a rerun writes byte-identical files (the test
suite checks this). Three textures start from the real grayscale photographs that scikit-image
ships (``skimage.data.grass``, ``gravel``, ``brick``); the others are procedural (periodic
fractal noise, periodic Voronoi cells, scattered shapes). Every texture is made tileable: noise
is synthesised in the Fourier domain (periodic by construction), shapes are drawn with
wrap-around, and photographs are replaced by their periodic component (Moisan's periodic plus
smooth decomposition), which removes the seams without blurring the texture.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import skimage.data
from scipy.spatial import cKDTree

SIZE = 512
PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 6]
HERE = Path(__file__).resolve().parent


# ----------------------------------------------------------------------------- building blocks
def fractal_noise(rng: np.random.Generator, size: int, beta: float, low_cut: float = 1.0):
    """Periodic noise with power spectrum ~ 1 / f**beta, scaled to [0, 1]."""
    fy = np.fft.fftfreq(size)[:, None] * size
    fx = np.fft.rfftfreq(size)[None, :] * size
    f = np.sqrt(fx**2 + fy**2)
    amp = np.where(f >= low_cut, 1.0 / np.maximum(f, 1e-9) ** (beta / 2.0), 0.0)
    spec = (rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape)) * amp
    img = np.fft.irfft2(spec, s=(size, size))
    img -= img.min()
    return img / max(img.max(), 1e-12)


def periodic_component(img: np.ndarray) -> np.ndarray:
    """Moisan's periodic component of a 2-D image: same texture, no seam when tiled."""
    u = img.astype(float)
    h, w = u.shape
    v = np.zeros_like(u)
    v[0, :] += u[-1, :] - u[0, :]
    v[-1, :] += u[0, :] - u[-1, :]
    v[:, 0] += u[:, -1] - u[:, 0]
    v[:, -1] += u[:, 0] - u[:, -1]
    q = np.arange(h)[:, None]
    r = np.arange(w)[None, :]
    den = 2 * np.cos(2 * np.pi * q / h) + 2 * np.cos(2 * np.pi * r / w) - 4
    den[0, 0] = 1.0
    s_hat = np.fft.fft2(v) / den
    s_hat[0, 0] = 0.0
    return u - np.real(np.fft.ifft2(s_hat))


def normalise(img: np.ndarray, lo_pct: float = 0.5, hi_pct: float = 99.5) -> np.ndarray:
    lo, hi = np.percentile(img, [lo_pct, hi_pct])
    return np.clip((img - lo) / max(hi - lo, 1e-9), 0.0, 1.0)


def colourise(gray: np.ndarray, stops: list[tuple[float, tuple[int, int, int]]]) -> np.ndarray:
    """Map gray values in [0, 1] through a piecewise-linear RGB palette -> float RGB [0, 255]."""
    xs = [s[0] for s in stops]
    out = np.empty(gray.shape + (3,))
    for c in range(3):
        out[..., c] = np.interp(gray, xs, [s[1][c] for s in stops])
    return out


def blend(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    return a * (1.0 - w[..., None]) + b * w[..., None]


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def periodic_voronoi(rng: np.random.Generator, size: int, n_cells: int, warp_px: float = 0.0):
    """Distances to the nearest and second-nearest of about ``n_cells`` sites on a torus, and
    the nearest site's index, each (size, size). ``warp_px`` displaces the query points by
    periodic noise so that cell edges wander like natural cracks."""
    g = int(round(np.sqrt(n_cells)))  # jittered grid: no two sites nearly coincide
    gy, gx = np.mgrid[0:g, 0:g].reshape(2, -1)
    jitter = rng.uniform(0.1, 0.9, size=(g * g, 2))
    sites = (np.stack([gx, gy], axis=1) + jitter) * (size / g)
    tree = cKDTree(sites, boxsize=size)
    yy, xx = np.mgrid[0:size, 0:size] + 0.5
    if warp_px:
        xx = xx + warp_px * (fractal_noise(rng, size, 3.0, low_cut=2.0) - 0.5)
        yy = yy + warp_px * (fractal_noise(rng, size, 3.0, low_cut=2.0) - 0.5)
    d, i = tree.query(np.stack([xx.ravel(), yy.ravel()], axis=1) % size, k=2)
    return d[:, 0].reshape(size, size), d[:, 1].reshape(size, size), i[:, 0].reshape(size, size)


def wrap_draw(canvas: np.ndarray, draw: Callable[[np.ndarray, float, float], None]) -> None:
    """Call ``draw(canvas, dx, dy)`` for the 9 periodic copies so shapes wrap across edges."""
    size = canvas.shape[0]
    for dy in (-size, 0, size):
        for dx in (-size, 0, size):
            draw(canvas, dx, dy)


def ellipse(canvas, centre, axes, angle_deg, colour) -> Callable:
    def draw(img, dx, dy):
        c = (int(round((centre[0] + dx) * 16)), int(round((centre[1] + dy) * 16)))
        a = (max(1, int(round(axes[0] * 16))), max(1, int(round(axes[1] * 16))))
        cv2.ellipse(img, c, a, angle_deg, 0, 360, colour, -1, cv2.LINE_AA, 4)

    wrap_draw(canvas, draw)


def grain(rng: np.random.Generator, size: int, strength: float) -> np.ndarray:
    """Fine per-pixel luminance grain, (size, size, 1)."""
    return (rng.standard_normal((size, size, 1)) * strength).astype(float)


def wrap_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur on a torus (the image wraps around its edges)."""
    pad = int(np.ceil(4 * sigma)) + 1
    padded = np.pad(img, [(pad, pad), (pad, pad)] + [(0, 0)] * (img.ndim - 2), mode="wrap")
    out = cv2.GaussianBlur(padded, (0, 0), sigma)
    return out[pad:-pad, pad:-pad]


# ----------------------------------------------------------------------------- the textures
def patchy_grass(rng):
    photo = normalise(periodic_component(skimage.data.grass()))
    green = colourise(
        photo,
        [(0.0, (22, 48, 14)), (0.45, (62, 112, 34)), (0.8, (118, 160, 60)), (1.0, (170, 196, 110))],
    )
    straw = colourise(photo, [(0.0, (70, 58, 30)), (0.5, (150, 128, 72)), (1.0, (214, 196, 140))])
    soil = colourise(photo, [(0.0, (48, 36, 24)), (1.0, (120, 96, 70))])
    patches = fractal_noise(rng, SIZE, 3.2, low_cut=2.0)
    dead = smoothstep(0.58, 0.68, patches)
    bare = smoothstep(0.78, 0.84, patches) * smoothstep(0.3, 0.7, fractal_noise(rng, SIZE, 2.5))
    img = blend(blend(green, straw, dead), soil, bare * 0.8)
    return img


def brick(rng):
    """Brick pavers in running bond (16 courses x 8 bricks per tile), surface detail from the
    photo. The photo itself is a wall in perspective, so it is not tiled directly."""
    size = SIZE
    photo = normalise(periodic_component(skimage.data.brick()))
    # fine high-pass of the photo (pits and grain of fired clay), clipped so that the photo's own
    # mortar lines do not show through
    detail = np.clip(photo - wrap_blur(photo, 1.2), -0.08, 0.08)
    photo_mortar = wrap_blur((photo > 0.55).astype(np.float32), 2.0) > 0.05
    detail = np.where(photo_mortar, np.roll(detail, (17, 29), axis=(0, 1)) * 0.5, detail)
    rows, cols = 16, 8
    bh, bw = size // rows, size // cols
    yy, xx = np.mgrid[0:size, 0:size]
    course = yy // bh
    shifted = (xx + (course % 2) * (bw // 2)) % size
    brick_id = course * cols + shifted // bw
    tone = rng.uniform(-0.5, 0.5, rows * cols)[brick_id]
    fy = yy % bh
    fx = shifted % bw
    mortar_px = 2.5
    dist = np.minimum(np.minimum(fy + 0.5, bh - fy - 0.5), np.minimum(fx + 0.5, bw - fx - 0.5))
    mortar = 1.0 - smoothstep(mortar_px - 1.0, mortar_px + 1.0, dist)
    edge_shade = smoothstep(mortar_px, mortar_px + 6.0, dist)  # worn, rounded brick edges
    clay = colourise(
        0.5 + 0.35 * tone + 1.5 * detail,
        [(0.0, (92, 34, 22)), (0.5, (150, 62, 40)), (1.0, (196, 104, 70))],
    )
    clay *= (0.82 + 0.18 * edge_shade)[..., None]
    joint = colourise(
        normalise(fractal_noise(rng, size, 1.5, low_cut=8.0)),
        [(0.0, (120, 112, 100)), (1.0, (176, 168, 152))],
    )
    img = blend(clay, joint, mortar)
    return img + grain(rng, size, 3.0)


def gravel(rng):
    photo = normalise(periodic_component(skimage.data.gravel()))
    img = colourise(
        photo,
        [
            (0.0, (44, 40, 36)),
            (0.4, (108, 100, 90)),
            (0.75, (160, 150, 136)),
            (1.0, (214, 206, 192)),
        ],
    )
    hue = fractal_noise(rng, SIZE, 1.2, low_cut=20.0)[..., None] - 0.5
    return img * (1.0 + 0.25 * hue * np.array([1.0, 0.8, 0.5]))


def sand(rng):
    size = SIZE
    yy, xx = np.mgrid[0:size, 0:size] / size
    warp = fractal_noise(rng, size, 3.5, low_cut=1.0) - 0.5
    ripples = 0.5 + 0.5 * np.sin(2 * np.pi * (9 * xx + 3 * yy + 1.4 * warp))
    base = 0.45 * fractal_noise(rng, size, 2.0, low_cut=2.0) + 0.25 * ripples
    fine = wrap_blur(rng.random((size, size)), 0.6)
    shade = normalise(base + 0.5 * fine)
    img = colourise(shade, [(0.0, (168, 140, 98)), (0.5, (208, 184, 138)), (1.0, (238, 222, 184))])
    return img + grain(rng, size, 6.0)


def concrete(rng):
    size = SIZE
    cloud = fractal_noise(rng, size, 2.6, low_cut=2.0)
    fine = fractal_noise(rng, size, 0.8, low_cut=30.0)
    shade = 0.6 * cloud + 0.4 * fine
    img = colourise(normalise(shade), [(0.0, (118, 118, 114)), (1.0, (178, 176, 170))])
    pores = (rng.random((size, size)) > 0.9975).astype(np.float32)
    pores = np.clip(wrap_blur(pores, 0.9) * 6.0, 0, 1)
    img = blend(img, np.full_like(img, 70.0), pores)
    # an expansion joint across the tile (seen every tile_m)
    joint = np.zeros((size, size))
    joint[:, size // 2 - 2 : size // 2 + 2] = 1.0
    joint = wrap_blur(joint, 1.0)
    img = blend(img, np.full_like(img, 82.0), joint * 0.9)
    return img + grain(rng, size, 4.0)


def dry_soil(rng):
    size = SIZE
    d1, d2, idx = periodic_voronoi(rng, size, 110, warp_px=24.0)
    edge = d2 - d1
    crack = 1.0 - smoothstep(1.0, 4.5, edge)
    rim = 1.0 - smoothstep(2.0, 9.0, edge)  # plates curl up and lighten at their rims
    plate = rng.uniform(-0.06, 0.06, idx.max() + 1)[idx]
    shade = 0.55 * fractal_noise(rng, size, 2.2, low_cut=3.0) + plate + 0.15 * rim
    shade += 0.25 * wrap_blur(rng.random((size, size)), 0.8)
    img = colourise(
        normalise(shade), [(0.0, (128, 96, 66)), (0.5, (164, 128, 90)), (1.0, (196, 164, 124))]
    )
    img = blend(img, np.full_like(img, 58.0) * [1.0, 0.8, 0.6], crack * 0.9)
    return img + grain(rng, size, 5.0)


def mud(rng):
    size = SIZE
    shade = fractal_noise(rng, size, 3.0, low_cut=1.0)
    img = colourise(shade, [(0.0, (42, 30, 20)), (0.5, (72, 52, 34)), (1.0, (98, 74, 50))])
    wet = smoothstep(0.62, 0.7, fractal_noise(rng, size, 3.4, low_cut=2.0))
    gloss = np.clip(wrap_blur(fractal_noise(rng, size, 1.0, low_cut=40.0), 1.5) * 1.6 - 0.6, 0, 1)
    img = blend(img, np.full_like(img, 36.0) * [1.0, 0.85, 0.7], wet * 0.7)
    img = img + (wet * gloss * 120.0)[..., None] * [0.8, 0.8, 0.85]
    return img + grain(rng, size, 3.0)


def leaves(rng):
    size = SIZE
    soil = colourise(fractal_noise(rng, size, 2.5), [(0.0, (40, 30, 20)), (1.0, (80, 60, 40))])
    canvas = np.ascontiguousarray(soil.astype(np.float32))
    palette = [
        (196, 96, 28),
        (170, 52, 24),
        (214, 160, 40),
        (120, 78, 36),
        (150, 110, 40),
        (96, 60, 30),
    ]
    for _ in range(900):
        c = rng.uniform(0, size, 2)
        a = rng.uniform(9, 22)
        colour = np.array(palette[rng.integers(len(palette))], float) * rng.uniform(0.75, 1.1)
        ellipse(
            canvas,
            c,
            (a, a * rng.uniform(0.45, 0.7)),
            float(rng.uniform(0, 180)),
            tuple(float(v) for v in colour),
        )
        if rng.random() < 0.5:  # midrib
            ang = np.deg2rad(rng.uniform(0, 180))
            ellipse(
                canvas, c, (a, 0.9), float(np.rad2deg(ang)), tuple(float(v) * 0.7 for v in colour)
            )
    shade = wrap_blur(fractal_noise(rng, size, 2.0, low_cut=3.0), 1.0)[..., None]
    return canvas * (0.8 + 0.4 * shade) + grain(rng, size, 4.0)


def snow(rng):
    size = SIZE
    drift = fractal_noise(rng, size, 3.0, low_cut=1.0)
    img = colourise(drift, [(0.0, (196, 208, 228)), (0.6, (232, 238, 246)), (1.0, (250, 252, 255))])
    sparkle = (rng.random((size, size)) > 0.996).astype(np.float32)
    sparkle = np.clip(wrap_blur(sparkle, 0.7) * 5.0, 0, 1)
    img = blend(img, np.full_like(img, 255.0), sparkle)
    return img + grain(rng, size, 2.5)


def asphalt(rng):
    size = SIZE
    base = colourise(
        fractal_noise(rng, size, 1.8, low_cut=2.0), [(0.0, (38, 38, 40)), (1.0, (66, 66, 68))]
    )
    stones = rng.random((size, size))
    stones = wrap_blur((stones > 0.93).astype(np.float32), 0.8)
    stones = np.clip(stones * 3.0, 0, 1) * rng.uniform(0.4, 1.0, (size, size))
    img = base + (stones * 80.0)[..., None]
    return img + grain(rng, size, 7.0)


def cobblestone(rng):
    size = SIZE
    d1, d2, idx = periodic_voronoi(rng, size, 64, warp_px=10.0)
    edge = d2 - d1
    dome = smoothstep(0.0, 14.0, edge)
    tone = rng.uniform(0.55, 1.0, idx.max() + 1)[idx]
    warm = rng.uniform(-0.06, 0.06, idx.max() + 1)[idx]
    shade = tone * (0.55 + 0.45 * dome) * (0.85 + 0.3 * fractal_noise(rng, size, 1.5, 8.0))
    img = shade[..., None] * np.array([150.0, 146.0, 140.0])
    img *= 1.0 + warm[..., None] * np.array([1.0, 0.0, -1.0])
    gap = 1.0 - smoothstep(1.0, 4.0, edge)
    img = blend(img, np.full_like(img, 40.0), gap)
    return img + grain(rng, size, 5.0)


def mulch(rng):
    size = SIZE
    canvas = np.ascontiguousarray(
        colourise(fractal_noise(rng, size, 2.0), [(0.0, (34, 22, 14)), (1.0, (60, 40, 26))]).astype(
            np.float32
        )
    )
    for _ in range(1400):
        c = rng.uniform(0, size, 2)
        length = rng.uniform(8, 26)
        colour = np.array([124, 80, 46], float) * rng.uniform(0.55, 1.25)
        ellipse(
            canvas,
            c,
            (length, rng.uniform(1.5, 3.5)),
            float(rng.uniform(0, 180)),
            tuple(float(v) for v in colour),
        )
    return canvas + grain(rng, size, 5.0)


# name: (function, seed, mu, tile_m, provenance, method)
TEXTURES = {
    "patchy_grass": (
        patchy_grass,
        1,
        0.30,
        1.2,
        "skimage.data.grass (grayscale photo)",
        "periodic component of the photo, green palette; straw-coloured dead "
        "patches and bare soil from periodic fractal-noise masks",
    ),
    "brick": (
        brick,
        2,
        0.80,
        1.6,
        "skimage.data.brick (grayscale photo) + procedural",
        "running-bond paver layout (16 x 8 per tile, mortar joints, per-brick tone), "
        "clay surface detail from the high-passed periodic component of the photo",
    ),
    "gravel": (
        gravel,
        3,
        0.55,
        0.8,
        "skimage.data.gravel (grayscale photo)",
        "periodic component of the photo, grey-beige palette, per-stone hue noise",
    ),
    "sand": (
        sand,
        4,
        0.45,
        1.0,
        "procedural",
        "periodic fractal noise with warped wind ripples, beige palette, fine grain",
    ),
    "concrete": (
        concrete,
        5,
        0.60,
        1.5,
        "procedural",
        "low-contrast fractal noise, pores, an expansion joint every tile",
    ),
    "dry_soil": (
        dry_soil,
        6,
        0.50,
        1.2,
        "procedural",
        "noise-warped periodic Voronoi plates with dark cracks and light rims, brown",
    ),
    "mud": (
        mud,
        7,
        0.35,
        1.2,
        "procedural",
        "dark brown fractal noise, wet puddle mask with glossy highlights",
    ),
    "leaves": (
        leaves,
        8,
        0.40,
        1.0,
        "procedural",
        "900 wrapped leaf ellipses in autumn colours with midribs on dark soil",
    ),
    "snow": (
        snow,
        9,
        0.20,
        1.5,
        "procedural",
        "bluish-white drift shading from fractal noise, sparkles, fine grain",
    ),
    "asphalt": (
        asphalt,
        10,
        0.70,
        0.8,
        "procedural",
        "dark fractal noise with light aggregate speckle and strong grain",
    ),
    "cobblestone": (
        cobblestone,
        11,
        0.65,
        1.2,
        "procedural",
        "periodic Voronoi stones with domed shading, dark joints",
    ),
    "mulch": (
        mulch,
        12,
        0.45,
        1.0,
        "procedural",
        "1400 wrapped wood-chip slivers on a dark brown ground",
    ),
}


def to_uint8(img: np.ndarray) -> np.ndarray:
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def make_all() -> dict[str, np.ndarray]:
    """All textures as RGB uint8 (SIZE, SIZE, 3), by name."""
    out = {}
    for name, (fn, seed, *_rest) in TEXTURES.items():
        img = to_uint8(fn(np.random.default_rng(seed)))
        assert img.shape == (SIZE, SIZE, 3), (name, img.shape)
        out[name] = img
    return out


def index_yaml() -> str:
    lines = [
        "# Terrain textures: generated by textures/make_textures.py (do not edit by hand).",
        "# mu: default true friction coefficient; tile_m: world size of one tile [m].",
        "textures:",
    ]
    for name, (_fn, seed, mu, tile_m, provenance, method) in TEXTURES.items():
        lines += [
            f"  - name: {name}",
            f"    file: {name}.png",
            f"    mu: {mu}",
            f"    tile_m: {tile_m}",
            f"    size_px: {SIZE}",
            f"    seed: {seed}",
            f'    provenance: "{provenance}"',
            f'    method: "{method}"',
        ]
    return "\n".join(lines) + "\n"


def contact_sheet(images: dict[str, np.ndarray], thumb: int = 200, cols: int = 4) -> np.ndarray:
    """RGB grid of 2x2-tiled thumbnails (so seams would show) with names and mu."""
    names = list(images)
    rows = (len(names) + cols - 1) // cols
    label_h = 26
    sheet = np.full((rows * (thumb + label_h), cols * thumb, 3), 255, np.uint8)
    for k, name in enumerate(names):
        r, c = divmod(k, cols)
        tiled = np.tile(images[name], (2, 2, 1))
        small = cv2.resize(tiled, (thumb, thumb), interpolation=cv2.INTER_AREA)
        y0 = r * (thumb + label_h)
        sheet[y0 : y0 + thumb, c * thumb : (c + 1) * thumb] = small
        text = f"{name}  mu {TEXTURES[name][2]:.2f}"
        cv2.putText(
            sheet,
            text,
            (c * thumb + 6, y0 + thumb + 18),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.48,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    return sheet


def write_png(path: Path, rgb: np.ndarray) -> None:
    ok = cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), PNG_PARAMS)
    if not ok:
        raise OSError(f"could not write {path}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE, help="output folder (default: here)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    images = make_all()
    for name, img in images.items():
        write_png(args.out / f"{name}.png", img)
    (args.out / "index.yaml").write_text(index_yaml())
    write_png(args.out / "contact_sheet.png", contact_sheet(images))
    print(f"wrote {len(images)} textures, index.yaml and contact_sheet.png to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
