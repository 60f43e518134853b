"""Smooth shading (docs/decisions/shading-normals.md): the shading normals a scene keeps from its
files or computes, their interpolation at a hit, the rule that no light reaches through the
geometric surface, and renders against the analytic sphere and across strategies."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import wavlight
from wavlight import camera, meshes
from wavlight.envmap import Environment
from wavlight.raytrace import RayTracer

B = np.array([0.3, 0.8, 0.2])   # the linear map's gradient: L(w) = 1 + B . w
ALBEDO = 0.5


def _linear_map(width=256, height=128):
    """Texels of L(w) = 1 + B . w at their centres' directions: a lambert surface of normal n under
    it reflects ALBEDO (1 + 2/3 B . n) (the irradiance of a linear radiance, pi + 2 pi / 3 B . n)."""
    env = Environment(np.ones((height, width, 3), np.float32))
    col, row = np.meshgrid(np.arange(width), np.arange(height))
    uv = np.stack([(col.ravel() + 0.5) / width, (row.ravel() + 0.5) / height], 1)
    d = env.square_to_world(uv)
    assert np.all(env.texel_index(d) == np.arange(width * height))   # the square is the image
    return np.repeat((1.0 + d @ B)[:, None], 3, 1).reshape(height, width, 3).astype(np.float32)


def _sphere(face_normals=False, subdivisions=2, size=40, spp=2048):
    return wavlight.load_dict({
        "render": {"width": size, "height": size, "spp": spp},
        "camera": {"eye": [0.0, 0.0, 4.0], "target": [0.0, 0.0, 0.0], "fov_y": 32.0},
        "environment": {"pixels": _linear_map()},
        "objects": [{"shape": "sphere", "radius": 1.0, "subdivisions": subdivisions, "material": "m",
                     "face_normals": face_normals}],
        "materials": {"m": {"type": "lambert", "albedo": [ALBEDO] * 3}}})


def _analytic_sphere(scene, k=64, seed=3):
    """Per pixel, the mean over k jittered rays of the analytic unit sphere's radiance, and whether
    every one of them hits the mesh (pixels inside the silhouette of both)."""
    w, h = scene.width, scene.height
    rng = np.random.default_rng(seed)
    px, py = np.repeat(np.arange(w * h) % w, k), np.repeat(np.arange(w * h) // w, k)
    o, d = camera.camera_rays(scene, px, py, rng.random((len(px), 2)), w, h)
    prim, _ = RayTracer(scene.vertices, scene.faces).intersect(o, d)
    d = d.astype(np.float64)
    eye = scene.camera.eye
    b = d @ eye
    t = -b - np.sqrt(np.maximum(b * b - (eye @ eye - 1.0), 0.0))
    value = ALBEDO * (1.0 + 2.0 / 3.0 * (eye + t[:, None] * d) @ B)
    inside = (prim >= 0).reshape(w * h, k).all(axis=1)
    return value.reshape(w * h, k).mean(axis=1).reshape(h, w), inside.reshape(h, w)


@pytest.mark.slow
def test_a_sphere_of_320_triangles_renders_as_the_analytic_sphere():
    """An icosphere of 320 faces with its vertex normals against the analytic sphere under a linear
    map: the smooth render's mean absolute error over the pixels inside the silhouette is within
    half the faceted one's and close to its own noise, and its mean error under 1% (what remains:
    the lobe cut at the geometric surface and the polyhedron inside the sphere)."""
    errors = {}
    for flat in (False, True):
        scene = _sphere(face_normals=flat)
        ref, inside = _analytic_sphere(scene)
        r = wavlight.render_full(scene, strategy="mis")
        rel = (r.image[..., 0] - ref)[inside] / ref[inside]
        noise = float(np.mean(r.stderr[..., 0][inside] / ref[inside]))
        errors[flat] = (float(np.mean(np.abs(rel))), float(np.mean(rel)), noise)
    (smooth_abs, smooth_mean, noise), (flat_abs, _, _) = errors[False], errors[True]
    assert smooth_abs < 0.5 * flat_abs, errors
    assert smooth_abs < 1.5 * noise, errors   # (the mean |.| of a normal error is 0.8 of its sd)
    assert abs(smooth_mean) < 0.01, errors


def _agree(a, b, mask):
    """Two renders agree within their standard errors: over the pixels in mask, the mean within 4
    standard errors, and at most 2% of pixels beyond 4 of their own (a per-pixel standard error of
    bsdf sampling under a sun is optimistic: its estimates are heavy-tailed)."""
    ma, mb = a.image[mask], b.image[mask]
    sa, sb = a.stderr[mask], b.stderr[mask]
    se = np.sqrt((sa ** 2).sum(0) + (sb ** 2).sum(0)) / len(ma)
    assert np.all(np.abs(ma.mean(0) - mb.mean(0)) < 4 * se + 1e-7), (ma.mean(0), mb.mean(0), se)
    z = np.abs(ma - mb) / np.sqrt(sa ** 2 + sb ** 2 + 1e-30)
    assert np.mean(z > 4) < 0.02


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ["light", "bsdf", "mis_comp", "wavelet"])
def test_the_strategies_agree_with_mis_on_the_smooth_sphere(strategy):
    scene = _sphere(subdivisions=1, size=24, spp=512)
    ref = wavlight.render_full(scene, strategy="mis", seed=1)
    got = wavlight.render_full(scene, strategy=strategy, seed=2)
    _agree(ref, got, np.isfinite(ref.stderr).all(axis=2) & (ref.image.sum(axis=2) > 0))


def test_face_normals_true_renders_with_the_geometric_normals():
    """face_normals = true is the faceted image: that of the same scene with no shading normals at
    all, and, through the interpolation, of shading normals that are each face's own normal."""
    smooth = _sphere(face_normals=False, subdivisions=1, size=24, spp=16)
    flat = _sphere(face_normals=True, subdivisions=1, size=24, spp=16)
    assert flat.normal_faces.min() == -1 == flat.normal_faces.max()
    v = smooth.vertices.astype(np.float64)
    f = smooth.faces
    own = meshes.unit_rows(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]))
    explicit = replace(smooth, normals=np.repeat(own, 3, axis=0).astype(np.float32),
                       normal_faces=np.arange(3 * len(f), dtype=np.int32).reshape(-1, 3))
    images = {name: wavlight.render(s, strategy="mis", seed=4) for name, s in
              (("flat", flat), ("none", replace(smooth, normal_faces=None)), ("explicit", explicit),
               ("smooth", smooth))}
    np.testing.assert_array_equal(images["flat"], images["none"])
    assert np.isclose(images["explicit"], images["flat"], rtol=1e-4, atol=1e-6).mean() > 0.999
    assert not np.allclose(images["smooth"], images["flat"], rtol=1e-2)


def _leaning_quad(tmp_path, pixels, eye, lean_deg=60.0, size=32, spp=64):
    """A single open quad (y = 0, 2 x 2) whose four corner normals lean lean_deg towards +x, from a
    PLY file with nx ny nz."""
    a = np.radians(lean_deg)
    n = (np.sin(a), np.cos(a), 0.0)
    rows = [f"{x} 0 {z} {n[0]} {n[1]} {n[2]}" for x, z in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    (tmp_path / "quad.ply").write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                                       "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
                                       "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
                                       + "\n".join(rows) + "\n3 0 2 1\n3 0 3 2\n")
    return wavlight.load_dict({
        "render": {"width": size, "height": size, "spp": spp},
        "camera": {"eye": list(eye), "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
        "environment": {"pixels": pixels},
        "objects": [{"mesh": "quad.ply", "material": "m"}],
        "materials": {"m": {"type": "ggx", "albedo": [0.9, 0.9, 0.9], "roughness": 0.4}}}, base_dir=tmp_path)


def test_a_ply_files_normals_are_kept(tmp_path):
    scene = _leaning_quad(tmp_path, np.ones((8, 16, 3), np.float32), (0.0, 3.0, 3.0))
    np.testing.assert_allclose(scene.normals, np.tile([np.sin(np.pi / 3), 0.5, 0.0], (4, 1)), atol=1e-6)
    np.testing.assert_array_equal(scene.normal_faces, [[0, 2, 1], [0, 3, 2]])


@pytest.mark.parametrize("strategy", ["uniform", "bsdf", "light", "mis", "mis_comp", "wavelet"])
def test_no_light_reaches_through_the_geometric_surface(tmp_path, strategy):
    """A map lit only below the horizon and an open quad whose shading normals lean 60 deg, seen
    from above: half of each shading hemisphere is below the quad, yet the quad stays black (its
    shadow rays would leave below the surface and reach the light: a leak), and nothing is NaN."""
    h, w = 64, 128
    below = np.zeros((h, w, 3), np.float32)
    below[h // 2 + 2:] = 5.0   # rows of directions below the horizon
    for eye in ((0.0, 3.0, 3.0), (-3.0, 1.2, 0.3)):   # the second sees the quad below its shading normal
        scene = _leaning_quad(tmp_path, below, eye)
        r = wavlight.render_full(scene, strategy=strategy)
        assert np.isfinite(r.image).all()
        on_quad = _inside(scene)
        assert on_quad.sum() > 50
        assert np.all(r.image[on_quad] == 0), strategy


def _inside(scene):
    """(H, W) bool: pixels whose four corners' rays hit the geometry (a convex quad: the whole pixel)."""
    w, h = scene.width, scene.height
    tracer = RayTracer(scene.vertices, scene.faces)
    hit = np.ones(w * h, bool)
    for corner in ((0.0, 0.0), (0.999, 0.0), (0.0, 0.999), (0.999, 0.999)):
        o, d = camera.camera_rays(scene, np.arange(w * h) % w, np.arange(w * h) // w, np.tile(corner, (w * h, 1)),
                                  w, h)
        hit &= tracer.intersect(o, d)[0] >= 0
    return hit.reshape(h, w)


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ["light", "bsdf", "wavelet"])
def test_the_strategies_agree_with_mis_where_the_shading_normal_leans(tmp_path, strategy):
    """Where the geometric surface cuts the shading lobe (and, from the second eye, the camera is
    below the shading normal as the file gives it), every strategy still agrees with mis."""
    from wavlight.envmap import procedural_sky

    # a broad sun: per-pixel standard errors stay honest for bsdf sampling too
    sky = procedural_sky(width=256, height=128, sun_radiance=30.0, sun_radius=12.0).astype(np.float32)
    for eye in ((0.0, 3.0, 3.0), (-3.0, 1.2, 0.3)):
        scene = _leaning_quad(tmp_path, sky, eye, size=24, spp=1024)
        ref = wavlight.render_full(scene, strategy="mis", seed=1)
        got = wavlight.render_full(scene, strategy=strategy, seed=2)
        _agree(ref, got, _inside(scene))


@pytest.mark.slow
def test_the_smooth_sphere_renders_as_mitsuba_renders_it():
    """Mitsuba 3 (scalar_rgb) with the same corner normals, twosided diffuse, mis: the mean over the
    sphere's pixels within 4 standard errors of the difference (Mitsuba's per-pixel error taken
    from wavlight's, the same estimator), and the faceted render of the same scene is not."""
    pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (pip install 'wavlight[peers]')")
    from wavlight.evaluation import peers

    mean = {}
    for flat in (False, True):
        scene = _sphere(face_normals=flat, subdivisions=1, size=32, spp=1024)
        _, inside = _analytic_sphere(scene)
        ours = wavlight.render_full(scene, strategy="mis")
        mean[flat] = float(ours.image[inside].mean())
        se = float(np.sqrt(2.0 * (ours.stderr[inside] ** 2).sum()) / ours.image[inside].size)
        if not flat:
            variant = peers.VARIANT
            peers.VARIANT = "scalar_rgb"   # (the LLVM variant needs a newer libLLVM than some systems have)
            try:
                theirs = peers.render_mitsuba(scene, "mis", spp=1024)
            finally:
                peers.VARIANT = variant
            assert abs(mean[flat] - float(theirs.image[inside].mean())) < 4 * se, (mean, se)
    assert abs(mean[True] - mean[False]) > 8 * se, (mean, se)


def test_interpolated_normals_at_corners_and_centre():
    """RayTracer.hit: at a corner the corner's normal, at the centre the normalised mean, turned
    towards the viewer; corners that cancel give the geometric normal."""
    v = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.int32([[0, 1, 2]])
    normals = meshes.unit_rows(np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], np.float64)).astype(np.float32)
    tracer = RayTracer(v, f, normals=normals, normal_faces=[[0, 1, 2]])
    eye = np.float32([0.2, 0.2, 2.0])
    o = np.tile(eye, (3, 1))
    targets = np.float32([[1e-3, 1e-3, 0], [1 / 3, 1 / 3, 0], [0.999, 1e-3, 0]])
    d = meshes.unit_rows(targets - o).astype(np.float32)
    prim, t, u, w = tracer.intersect_uv(o, d)
    n, g, _, _ = tracer.hit(eye, d, t, prim, u, w)
    np.testing.assert_allclose(g, np.tile([0, 0, 1], (3, 1)), atol=1e-6)
    np.testing.assert_allclose(n[0], normals[0], atol=2e-3)
    np.testing.assert_allclose(n[1], meshes.unit_rows(normals.sum(0, keepdims=True))[0], atol=1e-5)
    np.testing.assert_allclose(n[2], normals[1], atol=2e-3)
    below = np.tile(eye * np.float32([1, 1, -1]), (3, 1))   # from below: both turned towards it
    prim, t, u, w = tracer.intersect_uv(below, meshes.unit_rows(targets - below).astype(np.float32))
    n2, g2, _, _ = tracer.hit(below[0], meshes.unit_rows(targets - below).astype(np.float32), t, prim, u, w)
    assert np.all(g2[:, 2] < 0) and np.all(np.einsum("ij,ij->i", n2, n) < 0)
    cancel = RayTracer(v, f, normals=np.float32([[1, 0, 0], [-1, 0, 0]]), normal_faces=[[0, 1, 0]])
    prim, t, u, w = cancel.intersect_uv(o[:1], np.float32([[0, 0, -1]]))
    n3, g3, _, _ = cancel.hit(eye, np.float32([[0, 0, -1]]), t, prim, np.float32([0.5]), np.float32([0.0]))
    np.testing.assert_array_equal(n3, g3)


def test_normals_follow_scale_rotate_and_moves():
    """A sphere scaled by (2, 1, 1): its normals go with the inverse transpose (radial ones become
    (x / 2, y, z) normalised, here from its vertices), then the rotation; moving the object turns
    them with it."""
    d = {"render": {"width": 8, "height": 8, "spp": 1},
         "environment": {"pixels": np.ones((8, 16, 3), np.float32)},
         "objects": [{"shape": "sphere", "subdivisions": 1, "scale": [2.0, 1.0, 1.0], "rotate": [0, 0, 1, 90],
                      "name": "s"}]}
    scene = wavlight.load_dict(d)
    ob = scene.find_object("s")
    want = meshes.unit_rows(ob.local / np.array([4.0, 1.0, 1.0])) @ wavlight.scene.rotation([0, 0, 1, 90]).T
    np.testing.assert_allclose(scene.normals, want, atol=1e-6)
    moved = scene.moved(ob, rotate=[0, 1, 0, 90])
    np.testing.assert_allclose(moved.normals, want @ wavlight.scene.rotation([0, 0, 1, 90])
                               @ wavlight.scene.rotation([0, 1, 0, 90]).T, atol=1e-6)
    assert len(scene.without(ob).normal_faces) == 0


def test_obj_normals_per_corner_and_computed_where_missing(tmp_path):
    (tmp_path / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nvn 0 1 1\n"
                                    "f 1//1 2//2 3//1\nf 2 4 3\n")
    scene = wavlight.load_dict({"environment": {"pixels": np.ones((8, 16, 3), np.float32)},
                                "objects": [{"mesh": "a.obj"}]}, base_dir=tmp_path)
    rows = scene.normals[scene.normal_faces]
    np.testing.assert_allclose(rows[0], [[0, 0, 1], [0, 2 ** -0.5, 2 ** -0.5], [0, 0, 1]], atol=1e-6)
    np.testing.assert_allclose(rows[1], np.tile([0, 0, 1], (3, 1)), atol=1e-6)   # computed: the plane's


def test_gltf_normals_are_kept_through_node_transforms(tmp_path):
    trimesh = pytest.importorskip("trimesh", reason="glTF files are read through trimesh")
    box = trimesh.creation.icosphere(1)
    odd = np.tile([0.0, 0.0, 1.0], (len(box.vertices), 1))
    mesh = trimesh.Trimesh(box.vertices, box.faces, vertex_normals=odd, process=False)
    sc = trimesh.Scene()
    sc.add_geometry(mesh, transform=trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    (tmp_path / "a.glb").write_bytes(sc.export(file_type="glb"))
    scene = wavlight.load_dict({"environment": {"pixels": np.ones((8, 16, 3), np.float32)},
                                "objects": [{"mesh": "a.glb"}]}, base_dir=tmp_path)
    np.testing.assert_allclose(scene.normals, np.tile([0.0, -1.0, 0.0], (len(scene.normals), 1)), atol=1e-6)
    assert len(scene.faces) == len(box.faces)


def test_area_weighted_vertex_normals():
    """Two faces meeting at vertex 0: its normal weights each face's normal by its area."""
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 1]], np.float64)
    f = np.array([[0, 1, 2], [0, 3, 1]])   # normals +z (area 2) and +y (area 1)
    n = meshes.vertex_normals(v, f)
    np.testing.assert_allclose(n[0], meshes.unit_rows(np.array([[0.0, 1.0, 2.0]]))[0])
    np.testing.assert_allclose(n[2], [0, 0, 1])


def test_face_normals_must_be_a_boolean():
    with pytest.raises(wavlight.SceneError, match=r"face_normals: must be true or false"):
        wavlight.load_dict({"environment": {"pixels": np.ones((8, 16, 3), np.float32)},
                            "objects": [{"shape": "sphere", "face_normals": 1}]})


def test_scenes_edited_in_python_have_their_normals_checked():
    from wavlight.scene import check_scene

    scene = _sphere(subdivisions=1, size=8, spp=1)
    check_scene(scene)
    check_scene(scene.faceted())
    assert scene.faceted().content_hash != scene.content_hash
    for bad, match in ((replace(scene, normal_faces=scene.normal_faces[:3]), "normal_faces \\(F, 3\\)"),
                       (replace(scene, normals=scene.normals * np.nan), "normals hold NaN"),
                       (replace(scene, normal_faces=scene.normal_faces + len(scene.normals)), "name rows")):
        with pytest.raises(wavlight.WavlightError, match=match):
            wavlight.render(bad, spp=1)
