"""Distant environment light: an equirectangular RGB image, looked up nearest-texel.

Lookup (scene-format doc, same u, v as Mitsuba 3's envmap): for a world direction d,
undo ``rotate_y`` (world = R_y * map), then u = atan2(d.x, -d.z) / 2 pi wrapped to
[0, 1), v = acos(d.y) / pi, texel (floor(u W), floor(v H)), row 0 at +Y.

Importance for light and product sampling lives on a 2^n x 2^n square in the
map's own lat-long parameterization (phi = 2 pi u, theta = pi v; 2^n >= the map's
width and height): each leaf holds the exact integral of luminance over its solid
angle (the map is piecewise constant, so it is a separable box sum). For maps
with power-of-two sizes every leaf lies inside one texel, so L / pdf is constant
within a texel but for the sin(theta) variation across the leaf, as in Mitsuba 3's
envmap; the pdf is positive wherever the map is. The square-to-sphere Jacobian is
du dv / d omega = 1 / (2 pi^2 sin theta).

The lighting is that piecewise-constant map everywhere. Only what the camera sees directly
(camera rays that miss every object) may be filtered instead: with ``background = "bilinear"``
(:data:`wavlight.options.BACKGROUND`), :meth:`Environment.eval_background` interpolates between
texel centres (:func:`bilinear`, wrapping in u, clamped in v), as the kernels' ``env_bilinear``
(kernels/sphere.h); with ``background = "none"`` they see nothing (0: the background hidden, what
Mitsuba calls hide_emitters; the lighting still the map). The kernels take the choice as
``-DBACKGROUND_MODE`` (:data:`BACKGROUND_MODE`).

The built-in procedural sky (``procedural = "sky"`` in a scene) is a smooth
gradient plus a small, very bright sun disk, made at 512 x 256 texels; see
:func:`procedural_sky` for its keys.
"""
from __future__ import annotations

import copy
import warnings

import numpy as np

from . import warp
from .options import BACKGROUND
from .errors import (ArgumentError, SanitisedInputWarning, WavlightError, check_int, check_number, check_real,
                     file_problem, shown)

LUMINANCE = np.array([0.2126, 0.7152, 0.0722], np.float32)
ONE_BELOW = float(np.nextafter(1.0, 0.0))
#: the kernels' -DBACKGROUND_MODE per :data:`wavlight.options.BACKGROUND` value (kernels/common.h)
BACKGROUND_MODE = {"nearest": 0, "bilinear": 1, "none": 2}
TREE_TOLERANCE = 0.01  # total-variation distance a coarser light tree may leave (Environment.light_levels)
MAX_TEXELS = 1 << 26


def _pnm_size(path: str):
    """(width, height) from a PFM / PNM header, or None for other files: OpenImageIO's PNM reader
    reads the whole file when it opens it (3.5 s and 1.1 GB for a 20000 x 20000 PFM), so that
    an absurd size is refused from the header first."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(256)
    except OSError:
        return None
    if len(head) < 2 or head[:1] != b"P" or head[1:2] not in b"Ff123456":
        return None
    words = b" ".join(line.split(b"#", 1)[0] for line in head.splitlines()).split()
    try:
        return int(words[1]), int(words[2])
    except (IndexError, ValueError):
        return None


def _oiio_error(text: str) -> str:
    """OpenImageIO's error text as one short line."""
    line = "; ".join(part.strip() for part in str(text or "").splitlines() if part.strip())
    return line if len(line) <= 200 else line[:197] + "..."


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Luminance (weights LUMINANCE) of colours (..., 3), in their float type, as the kernels
    compute it: r w0 + g w1 + b w2. Elementwise on purpose: a matrix-vector product calls
    OpenBLAS, whose worker threads then spin for a while beside the renderer's threads (on
    2 cores, 6.5% of a render's CPU time after each light tree's luminances)."""
    w = LUMINANCE.astype(rgb.dtype if rgb.dtype.kind == "f" else np.float64)
    return rgb[..., 0] * w[0] + rgb[..., 1] * w[1] + rgb[..., 2] * w[2]


def srgb_decode(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear (IEC 61966-2-1)."""
    x = np.asarray(x, np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def read_image(path: str) -> np.ndarray:
    """(H, W, 3) float32 linear RGB from any format OpenImageIO reads. Integer (LDR) images,
    such as 8-bit PNG or JPEG, hold sRGB-encoded values: they are decoded to linear, as
    Mitsuba 3 and pbrt-v4 do, with a warning (a light probe needs HDR: .hdr, .exr, .pfm)."""
    import OpenImageIO as oiio

    problem = file_problem(path)
    if problem is not None:   # (a FIFO would block the reader; a folder is not "no such file")
        raise WavlightError(f"{path}: {problem}")
    size = _pnm_size(path)
    if size is not None and size[0] * size[1] > MAX_TEXELS:   # before OpenImageIO reads the whole file
        raise WavlightError(f"{path}: image of {size[0]}x{size[1]} texels is too large "
                            f"(at most {MAX_TEXELS} texels, {MAX_TEXELS * 12 >> 20} MiB as float RGB)")
    config = oiio.ImageSpec()
    config.attribute("pnm:pfmflip", 1)  # PFM stores the bottom row first; read it upright
    inp = oiio.ImageInput.open(path, config)
    if inp is None:
        raise WavlightError(f"{path}: cannot read image ({_oiio_error(oiio.geterror()) or 'unknown format'})")
    try:
        spec = inp.spec()
        if spec.deep or spec.depth > 1:
            raise WavlightError(f"{path}: a {'deep' if spec.deep else 'volume'} image; an environment map is a "
                                "flat RGB image")
        if spec.width < 1 or spec.height < 1 or spec.nchannels < 1:
            raise WavlightError(f"{path}: an empty image ({spec.width}x{spec.height}, {spec.nchannels} channels)")
        if spec.width * spec.height > MAX_TEXELS:
            raise WavlightError(f"{path}: image of {spec.width}x{spec.height} texels is too large "
                                f"(at most {MAX_TEXELS} texels, {MAX_TEXELS * 12 >> 20} MiB as float RGB)")
        channels = min(spec.nchannels, 3)   # a file of 1000 channels is read as its first three
        px = inp.read_image(0, 0, 0, channels, oiio.FLOAT)
        err = _oiio_error(inp.geterror())
    except MemoryError:
        raise WavlightError(f"{path}: not enough memory to read a {spec.width}x{spec.height} image") from None
    finally:
        inp.close()
    if px is None or px.size == 0 or px.size != spec.width * spec.height * channels:
        raise WavlightError(f"{path}: cannot read pixels{f' ({err})' if err else ''}")
    px = np.asarray(px, np.float32).reshape(spec.height, spec.width, channels)
    if spec.format.basetype not in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE):
        px = srgb_decode(np.clip(px, 0.0, 1.0))
        warnings.warn(f"{path}: a low-dynamic-range ({spec.format}) image, read as sRGB and decoded to linear "
                      "values of at most 1 (HDR formats, .hdr .exr .pfm, keep the range)", stacklevel=2)
    if spec.nchannels == 1:
        px = np.repeat(px, 3, axis=2)
    elif spec.nchannels == 2:
        px = np.concatenate([px[..., :1]] * 3, axis=2)
    return np.ascontiguousarray(px[..., :3])


#: Radiance above this is refused: estimates (radiance x BRDF x cos / pdf) are float32, and
#: the light tree's sums too; past it they overflow to Inf. Below it an estimate can still
#: overflow where BRDF x cos / pdf exceeds ~3e8 (a ggx lobe of roughness 1e-4 seen by uniform
#: sampling): the renderer then refuses to write the image. Real light probes stay below 1e6;
#: a sun of 1e30 is tested.
MAX_RADIANCE = 1e30


def sanitize(pixels: np.ndarray, name: str) -> np.ndarray:
    """Replace NaN, Inf and negative texels with 0, with one warning that counts them."""
    bad = ~np.isfinite(pixels) | (pixels < 0)
    if bad.any():
        texels = int(bad.any(axis=-1).sum())
        warnings.warn(f"{name}: {texels} texel(s) with NaN, Inf or negative values: those values set to 0",
                      SanitisedInputWarning, stacklevel=2)
        pixels = np.where(bad, np.float32(0), pixels).astype(np.float32)
    return pixels


def _colour(where, name, value):
    c = check_real(where, name, value, finite=True)
    if c.shape != (3,) or np.any(c < 0):
        raise ArgumentError(f"{where}: {name} must be 3 numbers >= 0, got {shown(value)}")
    return tuple(float(x) for x in c)


def procedural_sky(sun_elevation=35.0, sun_azimuth=30.0, sun_radius=0.75, sun_radiance=2.0e4,
                   zenith=(0.25, 0.45, 0.95), horizon=(0.9, 0.95, 1.0), ground=(0.3, 0.27, 0.24),
                   width=512, height=256) -> np.ndarray:
    """A lat-long sky: zenith-to-horizon gradient, flat ground, sun disk.

    Angles in degrees; the sun's azimuth is measured from -Z towards +X (the u = az/360 column).
    Texels inside the disk have sun_radiance; those at its edge the fraction of them it covers
    (8 x 8 points per texel), scaled so that the sun keeps its power, sun_radiance x 2 pi (1 -
    cos r), exactly. A sun smaller than a texel (at 512 x 256 a texel is 0.7 degrees; the real
    sun's radius is 0.27) thus lights its texel(s) dimmer than sun_radiance, with its power.
    """
    where = "envmap.procedural_sky"
    sun_elevation = check_number(where, "sun_elevation", sun_elevation, -90.0, 90.0)
    sun_azimuth = check_number(where, "sun_azimuth", sun_azimuth)
    sun_radius = check_number(where, "sun_radius", sun_radius, 0.0, 90.0)
    if sun_radius == 0:
        raise ArgumentError(f"{where}: sun_radius must be in (0, 90] degrees, got 0")
    sun_radiance = check_number(where, "sun_radiance", sun_radiance, 0.0)
    zenith, horizon, ground = (_colour(where, k, v) for k, v in (("zenith", zenith), ("horizon", horizon),
                                                                  ("ground", ground)))
    width = check_int(where, "width", width, 1, 1 << 14)
    height = check_int(where, "height", height, 1, 1 << 13)
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    theta = v * np.pi
    phi = u * 2 * np.pi
    d = np.stack(np.broadcast_arrays(
        np.sin(theta)[:, None] * np.sin(phi)[None, :], np.cos(theta)[:, None] + 0 * phi[None, :],
        -np.sin(theta)[:, None] * np.cos(phi)[None, :]), -1)
    up = np.clip(d[..., 1], 0, 1)[..., None]
    t = up ** 0.4
    sky = (1 - t) * np.array(horizon) + t * np.array(zenith)
    img = np.where(d[..., 1:2] >= 0, sky, np.array(ground))
    el, az = np.radians(sun_elevation), np.radians(sun_azimuth)
    sun = np.array([np.cos(el) * np.sin(az), np.sin(el), -np.cos(el) * np.cos(az)])
    radius = np.radians(sun_radius)
    cov = _disk_coverage(d, sun, radius)
    omega = (2 * np.pi / width) * (np.cos(theta - np.pi / (2 * height)) - np.cos(theta + np.pi / (2 * height)))
    target = 2 * np.pi * (1 - np.cos(radius))
    edge = (cov > 0) & (cov < 1)
    full = float(((cov >= 1) * omega[:, None]).sum())
    partial = float((np.where(edge, cov, 0.0) * omega[:, None]).sum())
    if partial > 0 and target > full:   # the edge texels carry the rest of the disk's power
        cov = np.where(edge, cov * ((target - full) / partial), cov)
    elif full == 0 and partial == 0:    # no sample point fell inside: the centre's texel has it all
        row = min(int((np.pi / 2 - el) / np.pi * height), height - 1)
        col = int((az / (2 * np.pi)) % 1.0 * width) % width
        cov[row, col] = target / omega[row]
    inside = np.minimum(cov, 1.0)[..., None]
    img = img * (1 - inside) + cov[..., None] * sun_radiance * np.array([1.0, 0.95, 0.85])
    return img.astype(np.float32)


def _disk_coverage(d, center, radius, sub=8):
    """Fraction of each texel of a lat-long map, whose centre directions are d (H, W, 3), inside
    the disk of angular radius `radius` about the unit vector `center`, from sub x sub points
    per texel near the disk (0 elsewhere)."""
    height, width = d.shape[:2]
    cov = np.zeros((height, width))
    reach = radius + 2 * np.pi / min(width, 2 * height) * 1.5   # the disk plus a texel's diagonal
    near = d @ center > np.cos(min(reach, np.pi))
    near[0, :] |= center[1] > np.cos(reach)       # the pole rows' texels are wide in angle
    near[-1, :] |= -center[1] > np.cos(reach)
    rows, cols = np.nonzero(near)
    s = (np.arange(sub) + 0.5) / sub
    su, sv = (a.ravel()[None, :] for a in np.meshgrid(s, s))
    for a in range(0, len(rows), 16384):   # in blocks: a sun of 90 degrees covers half the map
        r, c = rows[a:a + 16384, None], cols[a:a + 16384, None]
        pu, pv = (c + su) / width * 2 * np.pi, (r + sv) / height * np.pi
        dots = (np.sin(pv) * np.sin(pu) * center[0] + np.cos(pv) * center[1]
                - np.sin(pv) * np.cos(pu) * center[2])
        cov[r[:, 0], c[:, 0]] = (dots > np.cos(radius)).mean(axis=1)
    return cov


def rotation_y(degrees: float) -> np.ndarray:
    """R_y for rotate_y: +90 sends +X to -Z (right-handed about +Y)."""
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def band_overlaps(leaf_edges, texel_edges, antiderivative):
    """For each leaf interval [leaf_edges[i], leaf_edges[i + 1]): the texel intervals it overlaps,
    as indices (L, B) and measures F(hi) - F(lo) of the overlaps (L, B), zero past the last one
    (B = the most texels any leaf overlaps; the bands of a matrix product)."""
    n_tex = len(texel_edges) - 1
    first = np.clip(np.searchsorted(texel_edges, leaf_edges[:-1], side="right") - 1, 0, n_tex - 1)
    last = np.clip(np.searchsorted(texel_edges, leaf_edges[1:], side="left") - 1, first, n_tex - 1)
    band = first[:, None] + np.arange(int((last - first).max()) + 1)
    idx = np.minimum(band, n_tex - 1)
    lo = np.maximum(leaf_edges[:-1, None], texel_edges[idx])
    hi = np.minimum(leaf_edges[1:, None], texel_edges[idx + 1])
    inside = (band <= last[:, None]) & (hi > lo)
    return idx, np.where(inside, antiderivative(hi) - antiderivative(lo), 0.0)


def bilinear(pixels: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 3) float32: the map ``pixels`` (H, W, 3) at points (u, v) (N,) of its own square,
    interpolated bilinearly between texel centres ((c + 1/2) / W, (r + 1/2) / H): wrapping in u
    (longitude: the last column's neighbour is the first), clamped in v (the first and last rows
    hold up to the poles). In float32, the steps of kernels/sphere.h ``env_bilinear``."""
    h, w = pixels.shape[:2]
    x = np.asarray(u, np.float32) * np.float32(w) - np.float32(0.5)
    y = np.clip(np.asarray(v, np.float32) * np.float32(h) - np.float32(0.5), np.float32(0.0), np.float32(h - 1))
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    c0 = np.mod(x0.astype(np.int64), w)
    c1 = np.where(c0 + 1 == w, 0, c0 + 1)
    r0 = np.minimum(y0.astype(np.int64), h - 1)
    r1 = np.minimum(r0 + 1, h - 1)
    flat = np.asarray(pixels, np.float32).reshape(-1, 3)
    top = flat[r0 * w + c0] * (np.float32(1.0) - fx) + flat[r0 * w + c1] * fx
    bottom = flat[r1 * w + c0] * (np.float32(1.0) - fx) + flat[r1 * w + c1] * fx
    return (top * (np.float32(1.0) - fy) + bottom * fy).astype(np.float32)


class Environment:
    """An equirectangular environment map with scale and rotate_y.

    pixels : (H, W, 3) float32, sanitised and multiplied by ``scale``.
    background : how camera rays that miss see it (:data:`wavlight.options.BACKGROUND`):
        ``nearest`` (the map itself), ``bilinear`` (:meth:`eval_background`) or ``none`` (black);
        display only.
    """

    def __init__(self, pixels: np.ndarray, scale: float = 1.0, rotate_y: float = 0.0, name="environment",
                 background: str = BACKGROUND.default):
        name = name if isinstance(name, str) else shown(name)
        self.background = BACKGROUND.check(background, f"Environment {name}")
        scale = check_number(f"Environment {name}", "scale", scale, 0.0)
        rotate_y = check_number(f"Environment {name}", "rotate_y", rotate_y)
        pixels = check_real(f"Environment {name}", "pixels", pixels)
        if pixels.ndim != 3 or pixels.shape[2] != 3 or pixels.shape[0] < 1 or pixels.shape[1] < 1:
            raise WavlightError(f"{name}: expected an (H, W, 3) image, got shape {pixels.shape}")
        if pixels.shape[0] * pixels.shape[1] > MAX_TEXELS:
            raise WavlightError(f"{name}: a map of {pixels.shape[1]}x{pixels.shape[0]} texels is too large "
                                f"(at most {MAX_TEXELS})")
        pixels = sanitize(np.asarray(pixels, np.float32), name)
        self.name = name
        self.pixels = np.ascontiguousarray(pixels * np.float32(scale))
        peak = float(self.pixels.max(initial=0.0))
        if not peak <= np.float32(MAX_RADIANCE):
            raise WavlightError(f"{name}: radiance up to {peak:.3g} (after scale {scale:g}); at most "
                                f"{MAX_RADIANCE:g} is supported (float32 estimates): rescale the map")
        self.height, self.width = self.pixels.shape[:2]
        self.rotate_y = float(rotate_y)
        self.map_from_world = rotation_y(rotate_y).T
        self.world_from_map = rotation_y(rotate_y)

    # -- lookup
    def texel_index(self, d_world: np.ndarray) -> np.ndarray:
        """Flat texel indices (row * W + col) for world directions (N, 3)."""
        uv = self.world_to_square(d_world)
        col = np.minimum((uv[:, 0] * self.width).astype(np.int64), self.width - 1)
        row = np.minimum((uv[:, 1] * self.height).astype(np.int64), self.height - 1)
        return row * self.width + col

    def eval(self, d_world: np.ndarray) -> np.ndarray:
        """Radiance (N, 3) float32 arriving from world directions d (N, 3) (nearest texel)."""
        return self.pixels.reshape(-1, 3)[self.texel_index(d_world)]   # (a view, not a cached copy)

    def eval_background(self, d_world: np.ndarray) -> np.ndarray:
        """Radiance (N, 3) float32 that camera rays along world directions d (N, 3) see where they
        miss: :meth:`eval` (nearest), :func:`bilinear` with ``background = "bilinear"``, or 0 with
        ``background = "none"`` (the background hidden)."""
        if self.background == "nearest":
            return self.eval(d_world)
        if self.background == "none":   # the background hidden: misses contribute 0
            return np.zeros((len(d_world), 3), np.float32)
        uv = self.world_to_square(np.asarray(d_world, np.float64))
        return bilinear(self.pixels, uv[:, 0], uv[:, 1])

    def with_background(self, background: str) -> "Environment":
        """This map (the same pixels, not a copy) seen by missing camera rays as ``background``."""
        if background == self.background:
            return self
        other = copy.copy(self)
        other.background = BACKGROUND.check(background, f"Environment {self.name}")
        return other

    @property
    def is_black(self) -> bool:
        return not np.any(self.pixels > 0)

    # -- importance on the lat-long square (for light and product sampling)
    def square_levels(self) -> int:
        """n with 2^n >= max(W, H) (at most 11): leaf columns and rows nest inside texels for 2^k maps."""
        n = 1
        while (1 << n) < max(self.width, self.height) and n < 11:
            n += 1
        return n

    def light_levels(self, tolerance: float = TREE_TOLERANCE) -> tuple[int, float]:
        """Tree depth chosen from the map's content, and the approximation error it leaves.

        The smallest n >= 2 whose leaves, taken as constant, are within ``tolerance`` in total
        variation, 0.5 sum |p_full - p_n| over the finest leaves, of the distribution at
        :meth:`square_levels` (a smooth overcast map needs few levels, a tiny sun all of
        them). Returns (n, that distance).
        """
        top = self.square_levels()
        tv_of = self._tree_tvs()
        for n in range(2, top):
            tv = tv_of(n)
            if tv <= tolerance:
                return n, tv
        return top, 0.0

    def tree_tv(self, n: int) -> float:
        """The total variation a light tree of depth n leaves (:meth:`light_levels`' measure; 0
        at the full depth and deeper): --json's ``light_tree_tv`` also where the depth is set
        by hand."""
        return self._tree_tvs()(n)

    def _tree_tvs(self):
        """n -> 0.5 sum |p_full - p_n| over the finest leaves, p_n the depth-n leaves spread
        evenly over the finest ones (float32 tree, as the walk's)."""
        from .haar.tree import build_reference, level_offset

        top = self.square_levels()
        full = build_reference(self.luminance_square(top))[0].astype(np.float64)
        total = full[0]
        side = 1 << top
        p_img = full[level_offset(top):].reshape(side, side) / total if total > 0 else None

        def tv(n):
            if p_img is None or n >= top:
                return 0.0
            k = 1 << (top - n)
            blocks = p_img.reshape(1 << n, k, 1 << n, k)
            coarse = blocks.sum(axis=(1, 3)) / (k * k)
            return 0.5 * float(np.abs(blocks - coarse[:, None, :, None]).sum())
        return tv

    def luminance_square(self, n_levels: int | None = None, compensated: bool = False) -> np.ndarray:
        """(2^n, 2^n) float64 leaf masses: the exact integral of luminance over each leaf's solid angle.

        Leaf (row y, column x) covers u in [x, x+1)/2^n (phi = 2 pi u) and v in [y, y+1)/2^n
        (theta = pi v) of the square parameterization. The map is piecewise constant, so the
        integral is separable: column overlaps in phi times row overlaps in cos(theta).

        ``compensated``: the integral of max(luminance - its mean over the sphere, 0) instead
        (MIS compensation, Karlik et al. 2019): a light sampler for MIS only, which leaves
        the texels dimmer than the mean to the BSDF sample. A map with no texel above its
        mean (a constant one) gives the integral of 1, uniform in solid angle.
        """
        n = self.square_levels() if n_levels is None else n_levels
        side = 1 << n
        lum = luminance(self.pixels.astype(np.float64))
        if compensated:
            cos_edges = np.cos(np.arange(self.height + 1) / self.height * np.pi)
            row_weight = cos_edges[:-1] - cos_edges[1:]                 # solid angle of a texel row / (2 pi / W)
            mean = float((lum * row_weight[:, None]).sum() / (2.0 * self.width))   # / (4 pi) * (2 pi / W)
            # texels within rounding of the mean are not above it (a constant map's mean comes
            # out a few ulp off, which would leave a distribution of rounding noise)
            lum = np.where(lum > mean * (1.0 + 1e-6), lum - mean, 0.0)
            if not np.any(lum > 0):
                lum = np.ones_like(lum)
        # rows: solid-angle overlap of leaf row i with texel row r, in cos(theta); columns: in phi.
        # Each leaf overlaps a band of a few texels, so the products rows @ lum @ cols run over
        # the bands only (the dense products took 70 ms per call at 1024^2).
        ri, rw = band_overlaps(np.arange(side + 1) / side * np.pi, np.arange(self.height + 1) / self.height * np.pi,
                                lambda x: -np.cos(x))
        ci, cw = band_overlaps(np.arange(side + 1) / side * 2 * np.pi,
                                np.arange(self.width + 1) / self.width * 2 * np.pi, lambda x: x)
        by_rows = sum(rw[:, b, None] * np.take(lum, ri[:, b], axis=0) for b in range(ri.shape[1]))     # (side, W)
        return sum(np.take(by_rows, ci[:, b], axis=1) * cw[None, :, b] for b in range(ci.shape[1]))  # (side, side)

    def square_to_world(self, uv: np.ndarray) -> np.ndarray:
        """Square points (N, 2) -> world directions (N, 3): phi = 2 pi u, theta = pi v, then rotate_y."""
        phi = 2 * np.pi * uv[:, 0]
        theta = np.pi * uv[:, 1]
        st = np.sin(theta)
        d = np.stack([np.sin(phi) * st, np.cos(theta), -np.cos(phi) * st], 1)
        return d @ self.world_from_map.T

    def world_to_square(self, d_world: np.ndarray) -> np.ndarray:
        """World directions (N, 3) -> square points (N, 2), the inverse of :meth:`square_to_world`."""
        d = d_world @ self.map_from_world.T
        u = np.arctan2(d[:, 0], -d[:, 2]) * warp.INV_2PI
        u = u - np.floor(u)
        v = np.arccos(np.clip(d[:, 1], -1.0, 1.0)) * warp.INV_PI
        return np.stack([np.minimum(u, ONE_BELOW), np.minimum(v, ONE_BELOW)], 1)

    @staticmethod
    def square_to_solid_angle(d_world: np.ndarray) -> np.ndarray:
        """Jacobian du dv / d omega = 1 / (2 pi^2 sin theta) at world directions (0 at the poles).

        rotate_y turns about +Y, so sin(theta) is the same in world and map frames.
        """
        s = np.hypot(d_world[:, 0], d_world[:, 2])  # sin(theta), accurate near the poles
        with np.errstate(divide="ignore"):
            return np.where(s > 0, 1.0 / (2 * np.pi ** 2 * np.where(s > 0, s, 1.0)), 0.0)
