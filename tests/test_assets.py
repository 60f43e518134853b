"""Mesh files with their materials and textures (wavlight/assets.py, wavlight/textures.py,
kernels/texture.h): the material mapping table, sRGB decoding, bilinear lookups with repeat
(kernel against twin), the parts of a GLB and of an OBJ + MTL made with trimesh in tmp_path,
a textured quad that renders its texture exactly, strategies that agree on the GLB, and
``wavlight render ASSET.glb --env MAP``.

Expected values come from the glTF 2.0 and MTL documents and from the sRGB transfer function
(IEC 61966-2-1) written out here, not from wavlight's code.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import wavlight
from assets_util import MTL, STRIPE_A, STRIPE_B, stripes_image, write_designer_glb, write_glb, write_obj
from scenes_util import camera_of, check_estimates
from wavlight import assets, bsdfs, textures


def srgb(code):
    """IEC 61966-2-1: 8-bit sRGB code -> linear value."""
    c = np.asarray(code, np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


# ----------------------------------------------------------------------------- the mapping table
@pytest.mark.parametrize("metallic, roughness, kind, alpha", [
    (1.0, 0.3, "ggx", 0.09), (0.5, 0.5, "ggx", 0.25), (0.49, 0.4, "plastic", 0.16), (0.0, 1.0, "plastic", 1.0),
    (None, None, "ggx", 1.0),        # glTF's defaults: metallic 1, roughness 1
    (1.0, 0.0, "ggx", 1e-4),         # alpha kept within the scene format's range
])
def test_gltf_mapping_table(metallic, roughness, kind, alpha):
    m = assets.gltf_material([0.2, 0.4, 0.6, 1.0], metallic, roughness)
    assert m.type == kind and m.alpha == pytest.approx(alpha)
    np.testing.assert_allclose(m.albedo, [0.2, 0.4, 0.6])
    if kind == "plastic":
        assert m.ior == 1.5
    np.testing.assert_allclose(assets.gltf_material(None, 1.0, 0.5).albedo, [1, 1, 1])   # base colour 1


@pytest.mark.parametrize("kd, ks, ns, kind, albedo, alpha", [
    ([0.5, 0.4, 0.3], None, None, "lambert", [0.5, 0.4, 0.3], 0.0),
    ([0.5, 0.4, 0.3], [0.0, 0.0, 0.0], 80.0, "lambert", [0.5, 0.4, 0.3], 0.0),
    ([0.2, 0.3, 0.6], [0.5, 0.5, 0.5], 50.0, "plastic", [0.2, 0.3, 0.6], math.sqrt(2 / 52)),
    ([0.0, 0.0, 0.0], [0.9, 0.6, 0.3], 198.0, "ggx", [0.9, 0.6, 0.3], 0.1),
    (None, None, None, "lambert", [0.8, 0.8, 0.8], 0.0),    # Kd absent: 0.8
    (0.25, 0.5, None, "plastic", [0.25] * 3, 1.0),           # one number for three; Ns absent: alpha 1
])
def test_mtl_mapping_table(kd, ks, ns, kind, albedo, alpha):
    m = assets.mtl_material(kd, ks, ns)
    assert m.type == kind and m.alpha == pytest.approx(alpha)
    np.testing.assert_allclose(m.albedo, albedo)


# ----------------------------------------------------------------------------- textures
def test_srgb_decoding():
    codes = np.arange(256, dtype=np.uint8).reshape(16, 16, 1).repeat(4, axis=2)
    got = textures.decode_srgb8(codes)
    assert got.shape == (16, 16, 3) and got.dtype == np.float32
    np.testing.assert_allclose(got[..., 0].ravel(), srgb(np.arange(256)), rtol=1e-6, atol=1e-9)


def test_bilinear_lookup_with_repeat():
    """Texel centres give the texel; a point between two centres their mean; whole periods of
    u and v change nothing; v = 1 is the image's top row (OpenGL's convention)."""
    rng = np.random.default_rng(5)
    tex = [rng.random((4, 6, 3)).astype(np.float32), rng.random((3, 5, 3)).astype(np.float32)]
    texels, table = textures.atlas(tex)
    t = tex[1]
    h, w = t.shape[:2]
    rows, cols = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    uv = np.stack([(cols.ravel() + 0.5) / w, 1 - (rows.ravel() + 0.5) / h], 1)
    ones = np.ones(len(uv), np.int64)
    np.testing.assert_allclose(textures.lookup(texels, table, ones, uv), t.reshape(-1, 3), atol=1e-6)
    np.testing.assert_allclose(textures.lookup(texels, table, ones, uv + [3.0, -2.0]), t.reshape(-1, 3), atol=1e-5)
    mid = textures.lookup(texels, table, [1], [[1.0 / w, 1 - 0.5 / h]])   # between columns 0 and 1 of row 0
    np.testing.assert_allclose(mid[0], (t[0, 0] + t[0, 1]) / 2, atol=1e-6)
    seam = textures.lookup(texels, table, [1], [[0.0, 1 - 0.5 / h]])      # the repeat: last and first column
    np.testing.assert_allclose(seam[0], (t[0, 0] + t[0, w - 1]) / 2, atol=1e-6)
    assert np.all(textures.lookup(texels, table, [-1], [[0.3, 0.3]]) == 1)  # no texture: 1


def test_texture_kernel_matches_numpy(device):
    """kernels/texture.h (texture_uv, texture_rgb through texture.cl) against textures.hit_uv and
    lookup: coordinates to float32 rounding (3 ulp of the largest |uv|), colours to 1e-5 of the
    texels' range from the kernel's own coordinates (bilinear is continuous, so the texel
    boundaries do not magnify rounding)."""
    from wavlight import cl

    rng = np.random.default_rng(3)
    tex = [rng.random((5, 7, 3)).astype(np.float32), rng.random((1, 3, 3)).astype(np.float32),
           rng.random((16, 16, 3)).astype(np.float32)]
    texels, table = textures.atlas(tex)
    nf, n = 50, 100_003   # not a multiple of 8: the last work-item's partial lanes
    face_uv = (rng.random((nf, 6)) * 8 - 4).astype(np.float32)
    face = rng.integers(0, nf, n).astype(np.int32)
    bary = rng.random((n, 2)).astype(np.float32)
    bary /= np.maximum(bary.sum(1, keepdims=True), 1)
    tex_id = rng.integers(-1, 3, n).astype(np.int32)
    q = cl.thread_queue()
    uv_out, rgb_out = cl.empty(8 * n), cl.empty(12 * n)
    cl.kernel(cl.program("texture.cl"), "texture_lookup")(
        q, (cl.items(n, cl.LANES),), None, cl.to_device(face_uv), cl.to_device(face), cl.to_device(bary),
        cl.to_device(tex_id), np.uint32(n), cl.to_device(texels), cl.to_device(table), uv_out, rgb_out)
    uv = cl.read(uv_out, (2, n), np.float32, q).T
    rgb = cl.read(rgb_out, (3, n), np.float32, q).T
    ref_uv = textures.hit_uv(face_uv, face, bary[:, 0], bary[:, 1])
    assert np.abs(uv - ref_uv).max() <= 3 * np.finfo(np.float32).eps * np.abs(face_uv).max()
    assert np.abs(rgb - textures.lookup(texels, table, tex_id, uv)).max() <= 1e-5
    assert np.all(rgb[tex_id < 0] == 1)


# ----------------------------------------------------------------------------- the files' parts
def _by_name(scene, word):
    (m,) = [k for k, m in enumerate(scene.materials) if m.name.endswith(word)]
    return m


def test_glb_parts(tmp_path):
    """Each part's mapped material, its node transform, its texture coordinates and its sRGB
    texture decoded once to linear values."""
    path = write_glb(tmp_path / "a.glb")
    scene = wavlight.load_dict({"environment": {"procedural": "sky"}, "objects": [{"mesh": str(path)}]})
    floor, gold = _by_name(scene, "floor"), _by_name(scene, "gold")
    mf, mg = scene.materials[floor], scene.materials[gold]
    assert mf.kind == mg.kind == bsdfs.GGX
    assert mf.param == pytest.approx(0.49) and mg.param == pytest.approx(0.09)
    np.testing.assert_allclose(mf.albedo, [1, 1, 1])
    np.testing.assert_allclose(mg.albedo, [1.0, 0.78, 0.34], atol=0.5 / 255)   # trimesh keeps 8 bits
    assert mg.texture == -1 and mf.texture == 0 and len(scene.textures) == 1
    want = srgb(np.where(np.arange(16)[None, :, None] % 2 == 0, STRIPE_A, STRIPE_B) * np.ones((8, 1, 1)))
    np.testing.assert_allclose(scene.textures[0], want, rtol=1e-6)
    gold_vertices = scene.vertices[np.unique(scene.faces[scene.face_material == gold])]
    np.testing.assert_allclose(gold_vertices.mean(0), [-0.7, 0.5, 0.0], atol=1e-3)   # the node's translation
    floor_uv = scene.vertex_uv[np.unique(scene.faces[scene.face_material == floor])]
    np.testing.assert_allclose(np.sort(floor_uv[:, 0]), [0, 0, 2, 2])


def test_obj_parts(tmp_path):
    """OBJ + MTL: Kd with map_Kd (lambert, textured), Kd alone (lambert), Kd + Ks + Ns (plastic:
    where this build has no plastic, the scene is refused in one line naming the file and the
    part), Ks with black Kd (ggx)."""
    metal = MTL.replace("Kd 0.2 0.3 0.6", "Kd 0 0 0")
    path = write_obj(tmp_path / "metal", mtl_text=metal)
    scene = wavlight.load_dict({"environment": {"procedural": "sky"}, "objects": [{"mesh": str(path)}]})
    tex, shiny, dull = (scene.materials[_by_name(scene, w)] for w in ("tex", "shiny", "dull"))
    assert (tex.kind, dull.kind, shiny.kind) == (bsdfs.LAMBERT, bsdfs.LAMBERT, bsdfs.GGX)
    np.testing.assert_allclose(tex.albedo, [0.8] * 3)
    np.testing.assert_allclose(dull.albedo, [0.5, 0.4, 0.3])
    np.testing.assert_allclose(shiny.albedo, [0.5] * 3)
    assert shiny.param == pytest.approx(math.sqrt(2 / 52)) and tex.texture == 0 and dull.texture == -1
    np.testing.assert_allclose(scene.textures[0], srgb(stripes_image(8, 4)), rtol=1e-6)

    path = write_obj(tmp_path / "plastic")
    d = {"environment": {"procedural": "sky"}, "objects": [{"mesh": str(path)}]}
    if "plastic" in bsdfs.TYPES:
        scene = wavlight.load_dict(d)
        shiny = scene.materials[_by_name(scene, "shiny")]
        assert shiny.kind == bsdfs.TYPES["plastic"] and shiny.param == pytest.approx(math.sqrt(2 / 52))
    else:
        with pytest.raises(wavlight.SceneError) as e:
            wavlight.load_dict(d)
        assert str(path) in str(e.value) and "'shiny'" in str(e.value) and "plastic" in str(e.value)
        assert "\n" not in str(e.value)


def test_designer_glb_parts(tmp_path):
    """The GLB of issue 38 named with no material: a textured non-metal floor and a red non-metal
    sphere map to plastic (ior 1.5), the gold sphere to ggx; every face is shaded smooth with the
    file's vertex normals (the exact sphere's radial directions, which trimesh's own normals of
    a low-poly icosphere are not)."""
    path = write_designer_glb(tmp_path / "d.glb")
    scene = wavlight.load_dict({"environment": {"procedural": "sky"}, "objects": [{"mesh": str(path)}]})
    floor, gold, red = (scene.materials[_by_name(scene, w)] for w in ("floor", "gold", "red"))
    assert floor.kind == red.kind == bsdfs.PLASTIC and gold.kind == bsdfs.GGX
    assert floor.ior == red.ior == 1.5 and floor.texture == 0 and red.texture == gold.texture == -1
    np.testing.assert_allclose(red.albedo, [0.8, 0.1, 0.1], atol=0.5 / 255)
    assert red.param == pytest.approx(0.16) and floor.param == pytest.approx(0.49)
    rows = np.asarray(scene.normal_faces)
    assert np.all(rows >= 0)
    for k, x in ((_by_name(scene, "gold"), -0.7), (_by_name(scene, "red"), 0.7)):
        sel = scene.face_material == k
        assert sel.sum() == 320
        corners = scene.vertices[scene.faces[sel]].reshape(-1, 3) - [x, 0.5, 0.0]
        radial = corners / np.linalg.norm(corners, axis=1, keepdims=True)
        np.testing.assert_allclose(scene.normals[rows[sel]].reshape(-1, 3), radial, atol=1e-5)


def test_object_material_overrides_every_part(tmp_path):
    path = write_glb(tmp_path / "a.glb", plastic_sphere=True)
    scene = wavlight.load_dict({"environment": {"procedural": "sky"}, "objects": [{"mesh": str(path), "material": "m"}],
                                "materials": {"m": {"type": "lambert", "albedo": [0.3, 0.3, 0.3]}}})
    assert np.all(scene.face_material == 0) and scene.textures == [] and not scene.textured
    assert len(scene.faces) == 2 + 2 * 1280


# ----------------------------------------------------------------------------- rendering
QUAD_OBJ = """mtllib q.mtl
v -1 0 -1
v 1 0 -1
v 1 0 1
v -1 0 1
vt 0 1
vt 1 1
vt 1 0
vt 0 0
usemtl q
f 1/1 3/3 2/2
f 1/1 4/4 3/3
"""


def _textured_quad(folder, w=40, h=40):
    """A lambert quad (Kd 0.8 times an 8 x 8 texture of 2 x 2 blocks of four texels) seen from
    above under a constant map of 1, and (H, W) masks and values: ``flat`` where a pixel's
    footprint lies where the bilinear lookup is flat (inside one block, between its texel
    centres), ``albedo`` 0.8 x the block's sRGB-decoded colour there. The quad's texture
    coordinates put v = 1 (the image's top row) at z = -1, the top of the picture."""
    import PIL.Image

    codes = np.array([[[250, 20, 20], [20, 250, 20]], [[20, 20, 250], [128, 128, 128]]], np.uint8)
    PIL.Image.fromarray(codes.repeat(4, axis=0).repeat(4, axis=1)).save(folder / "t.png")
    (folder / "q.mtl").write_text("newmtl q\nKd 0.8 0.8 0.8\nmap_Kd t.png\n")
    (folder / "q.obj").write_text(QUAD_OBJ)
    scene = wavlight.load_dict({
        "render": {"width": w, "height": h, "spp": 4},
        "camera": {"eye": [0.0, 3.0, 0.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 0.0, -1.0], "fov_y": 40.0},
        "environment": {"pixels": np.ones((8, 16, 3), np.float32)},
        "objects": [{"mesh": str(folder / "q.obj")}]})
    cam = camera_of(scene)
    corners = cam.pixel_rays(1)                                    # (H, W, 4, 3)
    t = -cam.eye[1] / corners[..., 1]
    x, z = cam.eye[0] + t * corners[..., 0], cam.eye[2] + t * corners[..., 2]
    u, v = (x + 1) / 2, 1 - (z + 1) / 2                            # the OBJ's vt at (x, z)
    col, row = u * 8 - 0.5, (1 - v) * 8 - 0.5                      # in texel-centre units
    block_c, block_r = np.floor((col + 0.5) / 4), np.floor((row + 0.5) / 4)
    inside = lambda c: (c % 4 >= 0) & (c % 4 <= 3) & (c >= 0) & (c <= 7)
    flat = (np.all(inside(col) & inside(row), -1) & np.all(block_c == block_c[..., :1], -1)
            & np.all(block_r == block_r[..., :1], -1))
    albedo = 0.8 * srgb(codes[block_r[..., 0].clip(0, 1).astype(int), block_c[..., 0].clip(0, 1).astype(int)])
    return scene, flat, albedo


def test_textured_quad_renders_its_texture(tmp_path):
    """The textured quad under a constant map of 1, with cosine sampling and nothing to shadow
    it: each estimate is exactly the albedo at the point, so the flat pixels are their block's
    0.8 x sRGB-decoded colour (orientation, sRGB decoding and the bilinear lookup end to end)."""
    scene, flat, albedo = _textured_quad(tmp_path)
    assert flat.sum() > 200
    result = wavlight.render_full(scene, strategy="cosine")
    check_estimates(result.image, result.stderr, albedo, flat, 4, atol=2e-5, rtol=2e-5, label="textured quad")


def test_lighting_bake_albedo_carries_the_texture(tmp_path):
    """The lighting bake's per-pixel albedo (relight/bake.py camera_samples) is the textured
    albedo: the flat pixels of the textured quad hold their block's colour."""
    from wavlight.raytrace import RayTracer
    from wavlight.relight import bake as bake_mod

    scene, flat, albedo = _textured_quad(tmp_path, 24, 24)
    ps = bake_mod.camera_samples(scene, RayTracer(scene.vertices, scene.faces), 24, 24, 0, 0, 24, 24, 4, 5, 0)
    got = ps.albedo.reshape(24, 24, 3)
    assert flat.sum() > 50
    np.testing.assert_allclose(got[flat], albedo[flat], rtol=2e-5, atol=2e-6)


def _primary_material(scene, w, h):
    from wavlight.raytrace import RayTracer

    cam = camera_of(scene, w, h)
    d = cam.centre_rays().reshape(-1, 3)
    prim, _ = RayTracer(scene.vertices, scene.faces).intersect(np.broadcast_to(cam.eye, d.shape), d)
    return np.where(prim >= 0, scene.face_material[np.maximum(prim, 0)], -1).reshape(h, w)


@pytest.mark.slow
def test_glb_strategies_agree_with_mis(tmp_path):
    """The GLB (a gold metal sphere, a metal floor with its stripes texture) under the indoor map:
    every kernel strategy's mean over the floor's and over the sphere's pixels agrees with mis
    within their standard errors (unbiased: only the sampling differs; the texture multiplies
    the albedo of every estimate alike)."""
    path = write_glb(tmp_path / "a.glb")
    w, h, spp = 48, 36, 64
    scene = wavlight.load_asset(path, "data:st_fagans_interior_512", w, h)
    which = _primary_material(scene, w, h)
    floor, gold = _by_name(scene, "floor"), _by_name(scene, "gold")
    assert (which == floor).sum() > 100 and (which == gold).sum() > 30
    ref = wavlight.render_full(scene, spp=spp, strategy="mis", seed=1)
    for strategy in ("bsdf", "light", "mis_comp", "wavelet"):
        r = wavlight.render_full(scene, spp=spp, strategy=strategy, seed=2)
        se = np.sqrt(r.stderr ** 2 + ref.stderr ** 2)
        for part in (floor, gold):
            check_estimates(r.image, se, ref.image, which == part, spp, per_pixel=False,
                            label=f"{strategy} against mis on {scene.materials[part].name}")


@pytest.mark.slow
def test_shade_rays_textured_kernel_matches_numpy():
    """shade_rays (kernels/shade.cl with -DTEXTURES=1) against shading.shade_rays_reference on
    the GLB: the same estimates (float32 against float64, the tolerance of
    test_shade_rays_kernel_matches_numpy) where the texture multiplies the albedo."""
    import tempfile
    from pathlib import Path

    from wavlight import camera, strategies
    from wavlight.raytrace import RayTracer
    from wavlight.shading import KernelShader, NumpyShader

    with tempfile.TemporaryDirectory() as folder:
        scene = wavlight.load_asset(write_glb(Path(folder) / "a.glb"), None, 64, 48)
    tracer = RayTracer(scene.vertices, scene.faces)
    rng = np.random.default_rng(8)
    count = 20_003
    o, d = camera.camera_rays(scene, rng.integers(0, 64, count), rng.integers(0, 48, count), rng.random((count, 2)),
                              64, 48)
    prim, t, bu, bv = tracer.intersect_uv(o, d)
    floor = _by_name(scene, "floor")
    assert (scene.face_material[prim[prim >= 0]] == floor).mean() > 0.3
    bary = np.stack([bu, bv], 1)
    u = rng.random((count, 4), dtype=np.float32)
    for name in ("mis", "wavelet"):
        strat = strategies.make(name)
        strat.prepare(scene.environment, scene.materials)
        got = KernelShader(scene, strat, tracer).shade_rays(scene.camera.eye, d, prim, t, u, bary)
        ref = NumpyShader(scene, strat, tracer).shade_rays(scene.camera.eye, d, prim, t, u, bary)
        hit = prim >= 0
        total_got = got.direct[:, hit] + got.value[:, :, hit].sum(0)
        total_ref = ref.direct[:, hit] + ref.value[:, :, hit].sum(0)
        close = np.isclose(total_got, total_ref, rtol=2e-3, atol=1e-4 * np.abs(total_ref).max())
        assert close.mean() > 0.999, f"{name}: {(~close).sum()} of {close.size} estimates differ"


def test_render_asset_frames_its_bounds(tmp_path):
    """``wavlight render ASSET.glb --env data:rooitou_park_512`` writes the image; without a glTF
    camera the camera frames the file's bounds (every corner of the box inside the image, the
    box filling most of it); with one, the file's camera is used."""
    from test_cli import run_inproc

    path = write_glb(tmp_path / "a.glb")
    out = tmp_path / "a.png"
    o = run_inproc("render", path, "--env", "data:rooitou_park_512", "--spp", 2, "--width", 48, "--height", 36,
                   "-o", out, "-q")
    assert o.code == 0 and out.exists(), o.describe()
    scene = wavlight.load_asset(path, "data:rooitou_park_512", 48, 36)
    lo, hi = scene.vertices.min(0), scene.vertices.max(0)
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    col, row = camera_of(scene).project(box)
    assert col.min() >= 0 and col.max() <= 48 and row.min() >= 0 and row.max() <= 36
    assert max((col.max() - col.min()) / 48, (row.max() - row.min()) / 36) > 0.8
    import trimesh

    cam_path = write_glb(tmp_path / "c.glb", camera=True)
    with_camera = wavlight.load_asset(cam_path, None)
    transform = trimesh.load_scene(cam_path).camera_transform    # glTF: the camera looks down its -Z
    assert with_camera.camera.fov_y == pytest.approx(40.0)
    np.testing.assert_allclose(with_camera.camera.eye, transform[:3, 3], atol=1e-9)
    view = with_camera.camera.target - with_camera.camera.eye
    np.testing.assert_allclose(view / np.linalg.norm(view), -transform[:3, 2], atol=1e-9)


@pytest.mark.parametrize("vary", ["view", "object"])
def test_bakes_without_textures_refuse_textured_scenes(tmp_path, vary):
    """The bakes that do not carry textures yet (view, object) refuse a textured scene in one
    line naming the scene, before any work, rather than render it untextured."""
    path = write_glb(tmp_path / "a.glb")
    scene = wavlight.load_dict({"environment": {"procedural": "sky"},
                                "objects": [{"mesh": str(path), "name": "asset"}]}, base_dir=tmp_path)
    with pytest.raises(wavlight.WavlightError) as e:
        wavlight.bake(scene, vary=vary, **({"object": "asset"} if vary == "object" else {}))
    assert "textures" in str(e.value) and vary in str(e.value) and "\n" not in str(e.value)


def test_object_bake_refuses_an_object_of_several_materials(tmp_path):
    """An object bake shades its moving object with one material: a mesh file of several parts
    (an untextured GLB of a metal floor and a gold sphere) is refused in one line, before any work."""
    path = write_glb(tmp_path / "a.glb", texture=False)
    scene = wavlight.load_dict({"environment": {"procedural": "sky"},
                                "objects": [{"mesh": str(path), "name": "asset"}]}, base_dir=tmp_path)
    assert not scene.textured and len(np.unique(scene.face_material)) == 2
    with pytest.raises(wavlight.WavlightError) as e:
        wavlight.bake(scene, vary="object", object="asset")
    assert "2 materials" in str(e.value) and "'asset'" in str(e.value) and "\n" not in str(e.value)


def _gltf_quad(path, png: bytes | None):
    """A glTF written by hand (no trimesh on the way out): the quad of QUAD_OBJ with glTF's own
    texture coordinates (0, 0 the image's top-left corner: the OBJ's vt with v turned), a
    metal material of base colour 0.8, and with ``png`` that image as its base-colour texture."""
    import base64
    import json

    pos = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], np.float32)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)       # (OBJ vt 0 1, 1 1, 1 0, 0 0) turned
    idx = np.array([0, 2, 1, 0, 3, 2], np.uint16)
    data = pos.tobytes() + uv.tobytes() + idx.tobytes()
    pbr = {"baseColorFactor": [0.8, 0.8, 0.8, 1.0], "metallicFactor": 1.0, "roughnessFactor": 0.6}
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"name": "quad", "primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1},
                                                        "indices": 2, "material": 0}]}],
           "materials": [{"name": "q", "pbrMetallicRoughness": pbr}],
           "buffers": [{"byteLength": len(data),
                        "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48,
                                                                              "byteLength": 32},
                           {"buffer": 0, "byteOffset": 80, "byteLength": 12}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                          "min": [-1, 0, -1], "max": [1, 0, 1]},
                         {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
                         {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}]}
    if png is not None:
        pbr["baseColorTexture"] = {"index": 0}
        doc["textures"] = [{"source": 0}]
        doc["images"] = [{"uri": "data:image/png;base64," + base64.b64encode(png).decode()}]
    path.write_text(json.dumps(doc))
    return path


def test_gltf_texture_coordinates_follow_the_gltf_convention(tmp_path):
    """A hand-written glTF quad (glTF's texture coordinates: (0, 0) the image's top-left) renders
    its texture the right way up: with the same seed, the textured image over the untextured one
    (the same metal; the texture only scales each estimate) is, at the flat pixels of the
    textured quad test, the block's sRGB-decoded colour."""
    import io

    import PIL.Image

    _, flat, albedo = _textured_quad(tmp_path)     # the OBJ quad's expected blocks (0.8 x the colours)
    buf = io.BytesIO()
    PIL.Image.open(tmp_path / "t.png").save(buf, format="PNG")
    images = []
    for name, png in (("t.gltf", buf.getvalue()), ("w.gltf", None)):
        scene = wavlight.load_dict({
            "render": {"width": 40, "height": 40, "spp": 4},
            "camera": {"eye": [0.0, 3.0, 0.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 0.0, -1.0], "fov_y": 40.0},
            "environment": {"pixels": np.ones((8, 16, 3), np.float32)},
            "objects": [{"mesh": str(_gltf_quad(tmp_path / name, png))}]})
        assert scene.textured == (png is not None)
        images.append(wavlight.render_full(scene, strategy="bsdf", seed=4).image)
    ratio = images[0][flat] / images[1][flat]
    np.testing.assert_allclose(ratio, albedo[flat] / 0.8, rtol=2e-5)


def test_texture_beyond_the_limit_falls_back_to_the_base_colour(tmp_path, monkeypatch):
    """A texture of more texels than textures.MAX_TEXTURE_TEXELS (lowered here to 100, below the
    stripes' 128) is not read: one warning naming the file and the part, the base colour alone."""
    monkeypatch.setattr(textures, "MAX_TEXTURE_TEXELS", 100)
    path = write_glb(tmp_path / "a.glb")
    with pytest.warns(wavlight.SanitisedInputWarning) as caught:
        scene = wavlight.load_dict({"environment": {"procedural": "sky"}, "objects": [{"mesh": str(path)}]})
    lines = [str(w.message) for w in caught]
    assert len(lines) == 1 and str(path) in lines[0] and "'floor'" in lines[0] and "16x8" in lines[0], lines
    assert scene.textures == [] and not scene.textured
