"""Helpers for the rendering tests: scene files, an independent pinhole camera, the lat-long
convention of ``shared/docs/scene-format.md`` and standard-error checks.

Everything here is written from the scene-format document, not from wavlight's code, so the
tests compare wavlight against an independent reading of the conventions.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from scipy import stats

import wavlight


# ----------------------------------------------------------------------------- children

def run_limited(code: str, *args, gigabytes: int, timeout: float, what: str):
    """Run ``code`` in a Python child whose address space is limited to ``gigabytes`` GB (so that
    code which allocated what it should refuse fails instead of filling the machine), with
    ``args`` as sys.argv[1:]; the test fails, naming ``what``, if the child outlives ``timeout``
    seconds. Returns (the finished process, its wall seconds)."""
    import subprocess
    import sys
    import time

    import pytest

    limit = (f"import resource\nresource.setrlimit(resource.RLIMIT_AS, ({gigabytes} << 30, {gigabytes} << 30))\n")
    t = time.perf_counter()
    try:
        p = subprocess.run([sys.executable, "-c", limit + code, *map(str, args)], capture_output=True, text=True,
                           timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{what} after {timeout:g} s")
    return p, time.perf_counter() - t


# ----------------------------------------------------------------------------- scenes
def scene_dict(*, render: dict, camera: dict, environment: dict, objects=(), materials=None) -> dict:
    """A scene as the dict that wavlight.load_dict takes (the TOML file's structure)."""
    return {"render": render, "camera": camera, "environment": environment, "objects": list(objects),
            "materials": materials or {}}


def toml_value(v):
    """One value as TOML text (for the tests that need a scene *file*: the command line)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, (str, Path)):
        return json.dumps(str(v))  # a TOML basic string is a JSON string
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


def toml_text(d: dict) -> str:
    """A scene dict (scene_dict's structure) as a TOML file's text."""
    lines = []
    for name in ("render", "camera", "environment"):
        if name in d:
            lines += [f"[{name}]"] + [f"{k} = {toml_value(v)}" for k, v in d[name].items()] + [""]
    for o in d.get("objects", ()):
        lines += ["[[objects]]"] + [f"{k} = {toml_value(v)}" for k, v in o.items()] + [""]
    for mname, m in d.get("materials", {}).items():
        lines += [f"[materials.{mname}]"] + [f"{k} = {toml_value(v)}" for k, v in m.items()] + [""]
    return "\n".join(lines)


def write_scene(folder: Path, *, name="scene.toml", **kw) -> Path:
    """Write a scene TOML file (scene_dict's keywords) into ``folder`` and return its path."""
    path = Path(folder) / name
    path.write_text(toml_text(scene_dict(**kw)))
    return path


def write_env(folder: Path, name: str, pixels) -> str:
    """Write an (H, W, 3) environment image (float32, .exr or .pfm); returns its file name."""
    wavlight.save_image(str(Path(folder) / name), np.asarray(pixels, np.float32))
    return name


def write_sun_sky(folder: Path, name: str = "sky.exr") -> Path:
    """A 64 x 32 sky, 1.5 at the zenith to 0.3 at the nadir, with a one-texel sun of 3000 (hard
    shadows), written to folder/name."""
    sky = (np.linspace(1.5, 0.3, 32)[:, None, None] * np.ones((32, 64, 3))).astype(np.float32)
    sky[8, 20] = 3000.0
    write_raw_image(folder / name, sky)
    return folder / name


def write_lamp_sky(folder: Path, name: str = "sky.exr", rng=None) -> Path:
    """A 64 x 32 sky, 2 at the zenith to 0.2 at the nadir, each texel times a uniform 0.7-1.3 of
    ``rng`` (default: seeded 3), with a one-texel light of 400 at row 6, column 40, written to
    folder/name."""
    rng = np.random.default_rng(3) if rng is None else rng
    sky = (np.linspace(2.0, 0.2, 32)[:, None, None] * rng.uniform(0.7, 1.3, (32, 64, 3))).astype(np.float32)
    sky[6, 40] = 400.0
    write_raw_image(Path(folder) / name, sky)
    return Path(folder) / name


def over_floor(obj: dict, *, width: int, height: int, target=(0.0, 0.4, 0.0), rotate_y: float = 15.0,
               material: str = "m") -> dict:
    """A scene dict: ``obj`` (an [[objects]] table; its material ``material``, ggx 0.3) over a lambert
    floor 6 wide, seen from (0, 2, 4) towards ``target``, under write_sun_sky's sky.exr turned by
    ``rotate_y``."""
    return {"render": {"width": width, "height": height},
            "camera": {"eye": [0.0, 2.0, 4.0], "target": list(target), "fov_y": 40.0},
            "environment": {"file": "sky.exr", "rotate_y": rotate_y},
            "objects": [{**obj, "material": material}, {"shape": "quad", "size": 6.0, "material": "floor"}],
            "materials": {material: {"type": "ggx", "albedo": [0.9, 0.8, 0.6], "roughness": 0.3},
                          "floor": {"type": "lambert", "albedo": [0.6, 0.6, 0.6]}}}


def write_raw_image(path, pixels):
    """Float RGB through OpenImageIO directly (wavlight.save_image refuses NaN / Inf on purpose)."""
    import OpenImageIO as oiio

    pixels = np.ascontiguousarray(pixels, np.float32)
    out = oiio.ImageOutput.create(str(path))
    assert out is not None, oiio.geterror()
    assert out.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, oiio.FLOAT))
    assert out.write_image(pixels)
    out.close()
    return path


def one_texel_map(row=16, col=40, w=64, h=32):
    """A black w x h map with one bright texel at (row, col)."""
    px = np.zeros((h, w, 3), np.float32)
    px[row, col] = (100.0, 80.0, 60.0)
    return px


def map3x2():
    """A 3 x 2 map with a black texel and distinct colours."""
    return np.array([[[1.0, 0.5, 0.2], [4.0, 4.0, 4.0], [0.1, 0.2, 3.0]],
                     [[0.0, 0.0, 0.0], [9.0, 1.0, 1.0], [0.5, 0.5, 0.5]]], np.float32)


def shading_points(normal, view_deg, kind, param, count, albedo=(1.0, 1.0, 1.0)):
    """``count`` copies of one shading point: normal (world), wo at view_deg from it."""
    from wavlight import strategies, warp

    n = np.tile(np.asarray(normal, np.float64) / np.linalg.norm(normal), (count, 1))
    s, t = warp.frame(n)
    th = math.radians(view_deg)
    wo_world = math.sin(th) * s + math.cos(th) * n
    return strategies.ShadingPoints(np.zeros((count, 3)), n, s, t, warp.to_local(wo_world, s, t, n),
                                    np.full(count, kind, np.int32), np.full(count, float(param)),
                                    np.tile(np.asarray(albedo, np.float64), (count, 1)), np.zeros(count, np.int32))


def random_normals_views(rng, count):
    """count random unit normals n and unit view directions wo on their side (n . wo >= 0),
    (count, 3) float64 each: shading points in no particular configuration."""
    n = rng.normal(size=(count, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    wo = rng.normal(size=(count, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wo *= np.sign(np.einsum("ij,ij->i", wo, n))[:, None]
    return n, wo


def load(folder: Path, **kw) -> "wavlight.Scene":
    """A scene from scene_dict's keywords, its relative paths resolved against ``folder``."""
    return wavlight.load_dict(scene_dict(**kw), base_dir=folder)


# ----------------------------------------------------------------------------- lat-long convention
def rot_y(degrees: float) -> np.ndarray:
    """Right-handed rotation about +Y (counter-clockwise seen from +Y looking down)."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def dir_from_uv(u, v):
    """Map-frame unit direction for lat-long coordinates (u, v), inverting
    u = atan2(d.x, -d.z) / 2 pi, v = acos(d.y) / pi."""
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    phi, theta = 2 * np.pi * u, np.pi * v
    return np.stack([np.sin(theta) * np.sin(phi), np.cos(theta) + 0 * phi,
                     -np.sin(theta) * np.cos(phi)], -1)


def uv_from_dir(d):
    d = np.asarray(d, np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    u = np.arctan2(d[..., 0], -d[..., 2]) / (2 * np.pi)
    u = u - np.floor(u)
    v = np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi
    return u, v


def texel_dir(row, col, width, height, rotate_y=0.0, du=0.5, dv=0.5):
    """World direction of a point of texel (row, col) (its centre by default), after rotate_y."""
    d = dir_from_uv((col + du) / width, (row + dv) / height)
    return d @ rot_y(rotate_y).T


def texel_radius(row, col, width, height, rotate_y=0.0) -> float:
    """Largest angle (radians) between a texel's centre direction and any point of its border."""
    c = texel_dir(row, col, width, height, rotate_y)
    t = np.linspace(0, 1, 65)
    border = np.concatenate([np.stack([t, 0 * t], 1), np.stack([t, 1 + 0 * t], 1),
                             np.stack([0 * t, t], 1), np.stack([1 + 0 * t, t], 1)])
    d = texel_dir(row, col, width, height, rotate_y, border[:, 0], border[:, 1])
    return float(np.arccos(np.clip(d @ c, -1, 1)).max())


# ----------------------------------------------------------------------------- pinhole camera
class Pinhole:
    """The scene-format camera: fov_y is the full vertical field of view, row 0 at the top,
    column 0 at the left as seen by a viewer at eye looking at target with up up (no mirroring)."""

    def __init__(self, eye, target, up, fov_y, width, height):
        self.eye = np.asarray(eye, np.float64)
        self.width, self.height = width, height
        f = np.asarray(target, np.float64) - self.eye
        self.fwd = f / np.linalg.norm(f)
        r = np.cross(self.fwd, np.asarray(up, np.float64))
        self.right = r / np.linalg.norm(r)
        self.up = np.cross(self.right, self.fwd)
        self.tan = math.tan(math.radians(fov_y) / 2)

    def ray(self, col, row):
        """Unit direction through image point (col, row), in pixel units (0..W, 0..H)."""
        col, row = np.broadcast_arrays(np.asarray(col, np.float64), np.asarray(row, np.float64))
        x = (2 * col / self.width - 1) * self.tan * self.width / self.height
        y = (1 - 2 * row / self.height) * self.tan
        d = self.fwd + x[..., None] * self.right + y[..., None] * self.up
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def project(self, p):
        """Image point (col, row) in pixel units of a world point in front of the camera."""
        q = np.asarray(p, np.float64) - self.eye
        z = q @ self.fwd
        x = (q @ self.right) / z / (self.tan * self.width / self.height)
        y = (q @ self.up) / z / self.tan
        return (x + 1) * self.width / 2, (1 - y) * self.height / 2

    def pixel_rays(self, sub=1):
        """(H, W, K, 3) directions through a (sub+1) x (sub+1) grid of points of each pixel,
        corners included (sub = 1: the four corners)."""
        t = np.linspace(0, 1, sub + 1)
        oy, ox = np.meshgrid(t, t, indexing="ij")
        rows = np.arange(self.height)[:, None, None] + oy.ravel()[None, None, :]
        cols = np.arange(self.width)[None, :, None] + ox.ravel()[None, None, :]
        return self.ray(cols, rows)

    def pixel_samples(self, k):
        """(H, W, k*k, 3) directions through the midpoints of a k x k grid over each pixel."""
        t = (np.arange(k) + 0.5) / k
        oy, ox = np.meshgrid(t, t, indexing="ij")
        rows = np.arange(self.height)[:, None, None] + oy.ravel()[None, None, :]
        cols = np.arange(self.width)[None, :, None] + ox.ravel()[None, None, :]
        return self.ray(cols, rows)

    def centre_rays(self):
        rows, cols = np.meshgrid(np.arange(self.height) + 0.5, np.arange(self.width) + 0.5, indexing="ij")
        return self.ray(cols, rows)


def camera_of(scene, width=None, height=None) -> Pinhole:
    c = scene.camera
    return Pinhole(c.eye, c.target, c.up, c.fov_y, width or scene.width, height or scene.height)


def ray_sphere(o, d, centre, radius):
    """Distance to the first hit of rays (o, d) (unit d) with a sphere, NaN for a miss."""
    oc = np.asarray(o, np.float64) - np.asarray(centre, np.float64)
    b = np.sum(oc * d, -1)
    c = np.sum(oc * oc, -1) - radius * radius
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(disc)
    return np.where(disc >= 0, t, np.nan)


def line_distance(p, w, c):
    """Distance from point c to the lines through p along unit w."""
    return np.linalg.norm(np.cross(np.asarray(c, np.float64) - p, w), axis=-1)


# ----------------------------------------------------------------------------- statistics
ALPHA = 1e-5  # false-alarm probability allowed per check (per test case)


def z_threshold(n_tests: int, spp: int, alpha: float = ALPHA) -> float:
    """Two-sided Bonferroni threshold for n_tests standardised differences whose standard
    errors were estimated from spp samples each (Student t with spp - 1 degrees of freedom)."""
    return float(stats.t.isf(alpha / (2 * max(1, n_tests)), max(1, spp - 1)))


def check_estimates(mean, stderr, expected, mask, spp, *, slack=0.0, atol=1e-6, rtol=2e-6,
                    per_pixel=True, aggregate=True, exchangeable=False, label=""):
    """Assert that renderer means agree with expected values within their standard errors.

    mean, stderr : (H, W, 3); expected : broadcastable to (H, W, 3); mask : (H, W) bool.
    per_pixel: every masked pixel and channel, Bonferroni over the masked pixels.
    aggregate: the mean over masked pixels of (mean - expected) per channel, with the
    standard error sqrt(sum se^2) / m (pixels are independent estimates).
    slack: a bound on the known deterministic difference (e.g. the spread of the exact
    value over a pixel's footprint). A zero standard error requires equality up to atol, rtol.
    """
    mean = np.asarray(mean, np.float64)
    stderr = stderr_in = np.asarray(stderr, np.float64)
    expected = np.broadcast_to(np.asarray(expected, np.float64), mean.shape)
    mask = np.asarray(mask, bool)
    m = int(mask.sum())
    assert m > 0, f"{label}: no pixels to check"
    assert np.all(np.isfinite(mean[mask])), f"{label}: non-finite pixel values"
    fixed = slack + atol + rtol * np.abs(expected)
    diff = mean - expected
    msgs = []
    if per_pixel:
        z = z_threshold(m, spp)
        if exchangeable:
            pooled = np.sqrt((stderr[mask] ** 2).mean(axis=0))
            stderr = np.maximum(stderr, pooled)
        bad = mask[..., None] & (np.abs(diff) > z * stderr + fixed)
        if bad.any():
            rr, cc, ch = np.nonzero(bad)
            with np.errstate(divide="ignore", invalid="ignore"):
                zs = np.abs(diff) / stderr
            worst = np.argsort(-np.abs(diff[rr, cc, ch]))[:5]
            msgs.append(f"{label}: {len(rr)} of {m * 3} pixel channels differ beyond {z:.2f} stderr; worst: "
                        + "; ".join(f"({rr[i]},{cc[i]},{ch[i]}) got {mean[rr[i], cc[i], ch[i]]:.6g} "
                                    f"expected {expected[rr[i], cc[i], ch[i]]:.6g} "
                                    f"stderr {stderr[rr[i], cc[i], ch[i]]:.3g} z {zs[rr[i], cc[i], ch[i]]:.2f}"
                                    for i in worst))
    if aggregate:
        z = z_threshold(3, spp * m)
        d = diff[mask].mean(axis=0)
        se = np.sqrt((np.asarray(stderr_in, np.float64)[mask] ** 2).sum(axis=0)) / m
        tol = z * se + fixed[mask].mean(axis=0)
        if np.any(np.abs(d) > tol):
            msgs.append(f"{label}: mean over {m} pixels differs: got {mean[mask].mean(0)} expected "
                        f"{expected[mask].mean(0)} (diff {d}, aggregate stderr {se}, z {np.abs(d) / np.maximum(se, 1e-300)})")
    assert not msgs, "\n".join(msgs)
