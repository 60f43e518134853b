"""External peers: the same scene rendered by Mitsuba 3's ``direct`` integrator.

Optional (``pip install 'wavlight[peers]'``; the ``llvm_ad_rgb`` variant needs
Debian's ``libllvm19``; with ``DRJIT_LIBLLVM_PATH`` naming Debian 12's LLVM 14, Dr.Jit 1.5
leaves its LLVM backend inactive. Where the variable is unset it is set, before Mitsuba is
imported, to the first LLVM 19 library of :data:`LIBLLVM_19` that exists).

:func:`render_mitsuba` takes a loaded :class:`Scene` and renders it with equivalent settings:
pinhole camera (``fov_axis = "y"``), box filter, independent sampler, ``twosided`` BSDFs on meshes
with the scene's shading normals (per corner; ``face_normals`` for the faces shaded flat), the
environment rotated by ``rotate_y`` about +Y. Strategies: ``mis`` (1 emitter + 1
BSDF sample), ``mis_comp`` (the same with the envmap's ``mis_compensation``), ``light``
(emitter only), ``bsdf`` (BSDF only).

Equivalences and their limits:

- lambert -> ``diffuse``; ggx -> ``roughconductor`` (ggx, ``material = "none"``,
  ``specular_reflectance`` = albedo); plastic -> ``roughplastic`` (ggx, alpha, ``int_ior`` =
  ior, ``ext_ior`` 1, ``nonlinear`` false, ``diffuse_reflectance`` = albedo): the same BRDFs. phong has no Mitsuba
  counterpart: it is approximated by ggx with alpha = sqrt(2 / (n + 2)) and listed
  in ``stats["approximated_materials"]``.
- A base-colour texture (a mesh file's, wavlight.textures): its part is written as an OBJ with
  its texture coordinates (``vt``: Mitsuba's own reading of the OBJ convention). Its albedo is a
  ``bitmap`` texture (bilinear, repeat: the same lookup as wavlight's): where the material's
  albedo is 1 (glTF's base-colour factor 1) and the texels are the decoded 8-bit sRGB codes, the
  codes as an 8-bit PNG that Mitsuba decodes itself (sRGB, as for any PNG); otherwise the
  linear texels times the albedo (``raw``).
- The environment: Mitsuba's envmap uses the same (u, v) formula as wavlight but
  interpolates bilinearly between texel centres. wavlight looks up the nearest
  texel. We feed Mitsuba the map upsampled by nearest neighbour ``upsample`` times
  in each direction, so its bilinear blend only acts within half a fine texel of
  the original texel edges; :func:`envmap_mismatch` measures what is left (400k random
  directions, rotate_y 30): rooitou_park_1k at k = 8, mean
  |Mitsuba - wavlight| / mean = 2.0% (k = 4: 6.0%); debevec_grace_256x128 at k = 32: 2.2%
  (k = 8: 8.3%); the directions inside a blend band are 1 - (1 - 1/k)^2 of the square
  (23% at k = 8), everywhere else the lookups are identical.

:func:`part_agreement` measures a wavlight render against Mitsuba's renders of several seeds part
by part, over the pixels whose four corners see one part (:func:`part_pixels`): the relative
bias with its standard error, and the relMSE over the reference's own noise
(``benchmarks/mitsuba_peer.py --designer-glb``, tests/evaluation/test_peers.py).
"""
from __future__ import annotations

import os
import tempfile
import time

import numpy as np

from .. import bsdfs, textures
from ..integrator import RenderResult
from ..errors import WavlightError

VARIANT = "llvm_ad_rgb"
#: where Debian and Ubuntu put LLVM 19's library (``libllvm19``), the first that exists is Dr.Jit's
LIBLLVM_19 = ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
              "/usr/lib/aarch64-linux-gnu/libLLVM-19.so", "/usr/lib/aarch64-linux-gnu/libLLVM.so.19.1",
              "/usr/lib/llvm-19/lib/libLLVM.so", "/usr/lib/llvm-19/lib/libLLVM-19.so")
STRATEGIES = {"mis": (1, 1), "mis_comp": (1, 1), "light": (1, 0), "bsdf": (0, 1)}  # (emitter_samples, bsdf_samples)
# mis_comp: the envmap with mis_compensation = true, Mitsuba's MIS compensation


def _choose_libllvm():
    """Point Dr.Jit at LLVM 19 (``DRJIT_LIBLLVM_PATH``) where the variable is unset and Dr.Jit is
    not imported yet; the path chosen, or None."""
    import sys

    if os.environ.get("DRJIT_LIBLLVM_PATH") or "drjit" in sys.modules:
        return None
    for path in LIBLLVM_19:
        if os.path.isfile(path):
            os.environ["DRJIT_LIBLLVM_PATH"] = path
            return path
    return None


def _mitsuba():
    _choose_libllvm()
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError:
        raise WavlightError("Mitsuba 3 is not installed: pip install 'wavlight[peers]'") from None
    try:
        mi.set_variant(VARIANT)
    except Exception as e:  # the LLVM backend needs libLLVM (Debian: libllvm19)
        raise WavlightError(f"Mitsuba variant {VARIANT} unavailable ({str(e).splitlines()[0]}); "
                            "install Debian's libllvm19") from None
    return mi, dr


def available() -> bool:
    try:
        _mitsuba()
        return True
    except WavlightError:
        return False


def srgb_codes(texture):
    """(H, W, 3) uint8: the 8-bit sRGB codes whose decoding (wavlight.textures) gives the linear
    texels ``texture`` exactly, or None where some texel is no such decoding."""
    table = textures.SRGB_TO_LINEAR
    t = np.asarray(texture, np.float32)
    codes = np.clip(np.searchsorted(table, t), 0, 255)
    return codes.astype(np.uint8) if np.array_equal(table[codes], t) else None


def _texture(material, texture, folder):
    """The Mitsuba ``bitmap`` texture of an albedo ``texture`` (H, W, 3 linear) times the material's
    albedo: an sRGB PNG Mitsuba decodes itself where the albedo is 1 and the texels are decoded
    8-bit codes, else the linear product (``raw``)."""
    import PIL.Image

    lookup = {"type": "bitmap", "filter_type": "bilinear", "wrap_mode": "repeat"}
    codes = srgb_codes(texture) if np.all(np.asarray(material.albedo) == 1.0) else None
    if codes is not None and folder is not None:
        path = os.path.join(folder, f"texture_{len(os.listdir(folder))}.png")
        PIL.Image.fromarray(codes).save(path)
        return {**lookup, "filename": path, "raw": False}
    mi, _ = _mitsuba()
    texels = np.ascontiguousarray(texture * np.asarray(material.albedo, np.float32), np.float32)
    return {**lookup, "bitmap": mi.Bitmap(texels), "raw": True}


def _bsdf(material, texture=None, folder=None):
    """(Mitsuba BSDF dict, approximated) of a material; ``texture`` (H, W, 3) linear: its albedo
    is the bitmap of the texels times the material's albedo (:func:`_texture`, a PNG written
    into ``folder``)."""
    albedo = {"type": "rgb", "value": [float(x) for x in material.albedo]}
    if texture is not None:
        albedo = _texture(material, texture, folder)
    if material.kind == bsdfs.LAMBERT:
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": albedo}}, False
    if material.kind == bsdfs.PLASTIC:   # the same BSDF (docs/decisions/plastic-material.md)
        return {"type": "twosided", "bsdf": {"type": "roughplastic", "distribution": "ggx",
                                              "alpha": float(material.param), "int_ior": float(material.ior),
                                              "ext_ior": 1.0, "nonlinear": False,
                                              "diffuse_reflectance": albedo}}, False
    alpha = material.param if material.kind == bsdfs.GGX else float(np.sqrt(2.0 / (material.param + 2.0)))
    return {"type": "twosided", "bsdf": {"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                                          "material": "none", "specular_reflectance": albedo}}, \
        material.kind == bsdfs.PHONG


def _envmap_bitmap(mi, environment, upsample):
    px = np.repeat(np.repeat(environment.pixels, upsample, axis=0), upsample, axis=1)
    return mi.Bitmap(np.ascontiguousarray(px, np.float32))


def scene_dict(scene, strategy, width, height, spp, folder, upsample=8):
    """The Mitsuba scene dict for a wavlight Scene (meshes written as PLY files into ``folder``)."""
    import trimesh

    mi, _ = _mitsuba()
    if strategy not in STRATEGIES:
        raise WavlightError(f"no Mitsuba equivalent of strategy {strategy!r} ({' | '.join(STRATEGIES)})")
    em, bs = STRATEGIES[strategy]
    cam = scene.camera
    d = {"type": "scene",
         "integrator": {"type": "direct", "emitter_samples": em, "bsdf_samples": bs},
         "sensor": {"type": "perspective", "fov_axis": "y", "fov": float(cam.fov_y),
                    "to_world": mi.ScalarTransform4f().look_at(origin=cam.eye.tolist(), target=cam.target.tolist(),
                                                               up=cam.up.tolist()),
                    "film": {"type": "hdrfilm", "width": int(width), "height": int(height),
                             "rfilter": {"type": "box"}},
                    "sampler": {"type": "independent", "sample_count": int(spp)}},
         "environment": {"type": "envmap", "bitmap": _envmap_bitmap(mi, scene.environment, upsample),
                         "mis_compensation": strategy == "mis_comp",
                         "to_world": mi.ScalarTransform4f().rotate([0.0, 1.0, 0.0], scene.environment.rotate_y)}}
    approximated = []
    rows = (np.full((len(scene.faces), 3), -1, np.int64) if scene.normal_faces is None
            else np.asarray(scene.normal_faces, np.int64))
    smooth = np.all(rows >= 0, axis=1)
    for index, material in enumerate(scene.materials):
        texture = getattr(material, "texture", -1)
        textured = texture >= 0 and scene.vertex_uv is not None   # an OBJ with its texture coordinates
        bsdf, approx = _bsdf(material, scene.textures[texture], folder) if textured else _bsdf(material)
        if approx:
            approximated.append(material.name)
        for flat in (True, False):
            sel = (scene.face_material == index) & (smooth != flat)
            if not sel.any():
                continue
            name = f"material_{index}_{'flat' if flat else 'smooth'}"
            normals = None if flat else scene.normals[rows[sel]].reshape(-1, 3)
            if textured:
                path = os.path.join(folder, name + ".obj")
                _write_obj(path, scene.vertices, scene.faces[sel], scene.vertex_uv, normals)
            elif flat:
                path = os.path.join(folder, name + ".ply")
                trimesh.Trimesh(scene.vertices, scene.faces[sel], process=False).export(path)
            else:   # a vertex per corner, with that corner's normal
                path = os.path.join(folder, name + ".ply")
                _write_ply(path, scene.vertices[scene.faces[sel]].reshape(-1, 3), normals)
            d[f"shape_{index}_{int(flat)}"] = {"type": "obj" if textured else "ply", "filename": path,
                                               "face_normals": flat, "bsdf": bsdf}
    return d, approximated


def _write_obj(path, vertices, faces, uv, normals=None):
    """The faces' vertices with their texture coordinates as an OBJ (``v``, ``vt``, ``f a/a b/b c/c``),
    and with ``normals`` (3 F, 3: each corner's) its ``vn`` (``f a/a/i ...``)."""
    used, inverse = np.unique(faces, return_inverse=True)
    local = inverse.reshape(-1, 3) + 1
    with open(path, "w") as fh:
        np.savetxt(fh, vertices[used], fmt="v %.9g %.9g %.9g")
        np.savetxt(fh, uv[used], fmt="vt %.9g %.9g")
        if normals is None:
            np.savetxt(fh, np.repeat(local, 2, axis=1), fmt="f %d/%d %d/%d %d/%d")
        else:
            np.savetxt(fh, normals, fmt="vn %.9g %.9g %.9g")
            corner = np.arange(1, 3 * len(local) + 1).reshape(-1, 3)
            rows = np.stack([local, local, corner], axis=2).reshape(len(local), 9)
            np.savetxt(fh, rows, fmt="f %d/%d/%d %d/%d/%d %d/%d/%d")


def _write_ply(path, vertices, normals):
    """A binary PLY of triangles (0, 1, 2), (3, 4, 5), ... with vertex normals."""
    n = len(vertices)
    v = np.zeros(n, [("p", "<f4", 3), ("n", "<f4", 3)])
    v["p"], v["n"] = vertices, normals
    f = np.zeros(n // 3, [("c", "u1"), ("i", "<i4", 3)])
    f["c"], f["i"] = 3, np.arange(n, dtype=np.int32).reshape(-1, 3)
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n"
              f"property float z\nproperty float nx\nproperty float ny\nproperty float nz\nelement face {n // 3}\n"
              "property list uchar int vertex_indices\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii") + v.tobytes() + f.tobytes())


def render_mitsuba(scene, strategy="mis", spp=None, width=None, height=None, seed=None, upsample=8):
    """Render with Mitsuba 3 -> RenderResult (stderr is NaN: Mitsuba reports no per-pixel error).

    stats: setup_seconds (scene conversion and loading, plus a 1-spp JIT warm-up),
    render_seconds, samples_per_second, approximated_materials.
    """
    mi, dr = _mitsuba()
    spp = scene.spp if spp is None else int(spp)
    width = scene.width if width is None else int(width)
    height = scene.height if height is None else int(height)
    seed = scene.seed if seed is None else int(seed)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="wavlight-mitsuba-") as folder:
        d, approximated = scene_dict(scene, strategy, width, height, spp, folder, upsample)
        mi_scene = mi.load_dict(d)
    warm = mi.render(mi_scene, spp=1, seed=seed)
    dr.eval(warm)
    dr.sync_thread()
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    img = mi.render(mi_scene, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    seconds = time.perf_counter() - t0
    image = np.asarray(img, np.float32)[..., :3]
    stats = {"strategy": f"mitsuba:{strategy}", "spp": spp, "width": width, "height": height, "seed": seed,
             "setup_seconds": round(setup, 4), "render_seconds": round(seconds, 4),
             "samples_per_second": round(width * height * spp / seconds, 1),
             "approximated_materials": approximated, "mitsuba_version": mi.__version__}
    return RenderResult(image, np.full_like(image, np.nan), stats)


def envmap_mismatch(environment, count=200_000, upsample=8, seed=0, rtol=1e-3):
    """Fraction of random directions where Mitsuba's envmap (fed the upsampled map) differs
    from wavlight's nearest-texel lookup by more than ``rtol`` (relative, per channel)."""
    mi, dr = _mitsuba()
    emitter = mi.load_dict({"type": "envmap", "bitmap": _envmap_bitmap(mi, environment, upsample),
                            "to_world": mi.ScalarTransform4f().rotate([0.0, 1.0, 0.0], environment.rotate_y)})
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(count, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    si = dr.zeros(mi.SurfaceInteraction3f, count)
    si.wi = mi.Vector3f(-d[:, 0], -d[:, 1], -d[:, 2])  # eval looks up the direction -wi
    theirs = np.asarray(emitter.eval(si))
    theirs = theirs.T if theirs.shape[0] == 3 and theirs.shape[-1] != 3 else theirs
    ours = environment.eval(d)
    bad = np.abs(theirs - ours) > rtol * np.maximum(np.abs(ours), 1e-6)
    return float(bad.any(axis=1).mean())


def part_pixels(scene, width=None, height=None) -> np.ndarray:
    """(H, W) int: the material of the part each pixel sees through all four of its corners, -1
    where a corner sees the map or another part (silhouettes, where the renderers' direct lookups
    of the map differ, and the edges between parts)."""
    from .. import camera, raytrace

    w = scene.width if width is None else int(width)
    h = scene.height if height is None else int(height)
    tracer = raytrace.RayTracer(scene.vertices, scene.faces)
    py, px = np.divmod(np.arange(w * h), w)
    which = None
    for corner in ((0.01, 0.01), (0.99, 0.01), (0.01, 0.99), (0.99, 0.99)):
        o, d = camera.camera_rays(scene, px, py, np.tile(corner, (w * h, 1)), w, h)
        prim = tracer.intersect(np.ascontiguousarray(o), d)[0]
        k = np.where(prim >= 0, np.asarray(scene.face_material)[np.maximum(prim, 0)], -1)
        which = k if which is None else np.where(which == k, which, -1)
    return which.reshape(h, w)


def part_agreement(scene, ours, runs, eps=1e-2) -> dict:
    """wavlight's render ``ours`` (a RenderResult) against Mitsuba's ``runs`` ((S, H, W, 3), S >= 2
    independent seeds; the reference is their mean), per part (:func:`part_pixels`), keyed by
    material name:

    - ``bias`` (per channel): mean over the part's pixels of ours - reference, over the
      reference's mean; ``bias_se``: its standard error (ours' per-pixel standard errors and the
      reference's from its seeds' spread), relative likewise; ``bias_z`` = bias / bias_se.
    - ``relmse``: wavlight.evaluation.metrics.relmse of ours against the reference with the
      reference's own variance removed, mean of ((ours - reference)^2 - var) / (reference^2 + eps)
      (var: the variance of the reference, its seeds' variance over S): ours' relative MSE
      against the exact image; ``relmse_raw`` without the removal.
    - ``reference_noise``: the reference's own relative MSE, mean of var / (reference^2 + eps);
      ``relmse_ratio`` = relmse / reference_noise: for an unbiased render, ours' variance over
      the reference's (1 at equal noise); ``wavlight_noise``: ours' relative variance, from its
      per-pixel standard errors.
    """
    from . import metrics

    runs = np.asarray(runs, np.float64)
    seeds = len(runs)
    ref = runs.mean(0)
    ref_var = runs.var(0, ddof=1) / seeds
    which = part_pixels(scene, ref.shape[1], ref.shape[0])
    out = {}
    for k, material in enumerate(scene.materials):
        mask = which == k
        m = int(mask.sum())
        if m == 0:
            continue
        x, r = np.asarray(ours.image, np.float64)[mask], ref[mask]
        level = r.mean(0)
        se = np.sqrt((np.asarray(ours.stderr, np.float64)[mask] ** 2 + ref_var[mask]).sum(0)) / m
        diff = (x - r).mean(0)
        relmse = metrics.relmse(x, r, np.sqrt(ref_var[mask]), eps=eps)
        noise = float(np.mean(ref_var[mask] / (r * r + eps)))
        out[material.name] = {
            "type": {v: n for n, v in bsdfs.TYPES.items()}[material.kind],
            "pixels": m, "mean_mitsuba": level.tolist(), "bias": (diff / level).tolist(),
            "bias_se": (se / level).tolist(), "bias_z": (diff / se).tolist(),
            "relmse": relmse, "relmse_raw": metrics.relmse(x, r, eps=eps), "reference_noise": noise,
            "relmse_ratio": relmse / noise,
            "wavlight_noise": float(np.mean(np.asarray(ours.stderr, np.float64)[mask] ** 2 / (r * r + eps)))}
    return out
