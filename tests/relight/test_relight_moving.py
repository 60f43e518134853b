"""Frames in which one object moves (wavlight.relight.moving): unbiased against mis of the moved
scene (the whole frame, and its two estimators apart: wavelet where the object may be seen, the
static image minus the object's occlusion elsewhere), the kernels against their numpy twins,
through the command line, and the one-line errors of edits the bake holds fixed."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import wavlight
from scenes_util import over_floor, toml_text, write_sun_sky
from wavlight.cli.main import main
from wavlight.relight.moving import MovingObject


def scene_dict(translate=(0.0, 0.5, 0.0)):
    return over_floor({"shape": "sphere", "name": "ball", "translate": list(translate), "radius": 0.5,
                       "subdivisions": 3}, width=32, height=24, target=(0.0, 0.3, 0.0))


@pytest.fixture(scope="module")
def moving(tmp_path_factory, device):
    folder = tmp_path_factory.mktemp("moving")
    write_sun_sky(folder)                                  # a small sun: hard shadows
    (folder / "scene.toml").write_text(toml_text(scene_dict()))
    scene = wavlight.load_scene(folder / "scene.toml")
    tr = wavlight.bake(scene, folder / "ball.wlt", spp=4, levels=5, terms=256, priority="area", vary="object",
                       object="ball", static_spp=256)
    return folder, scene, tr


@pytest.mark.slow
@pytest.mark.parametrize("translate", [(0.0, 0.5, 0.0), (0.9, 0.5, -0.5)])
def test_frames_are_unbiased_against_mis_of_the_moved_scene(moving, translate):
    folder, scene, tr = moving
    r = MovingObject(tr, scene).frame(translate=translate, spp=32, seed=4)
    moved = wavlight.load_dict(scene_dict(translate), base_dir=folder)
    ref = wavlight.render_full(moved, spp=1024, strategy="mis", seed=9)
    var = r.stderr ** 2 + ref.stderr ** 2
    z_total = (r.image - ref.image).sum() / np.sqrt(var.sum())
    blocks = lambda a: a.reshape(4, 6, 4, 8, 3).sum(axis=(1, 3))   # noqa: E731  (48 sums of 48 pixels)
    z = blocks(r.image - ref.image) / np.sqrt(blocks(var))
    assert abs(z_total) < 3.3 and np.abs(z).max() < 3.9, (z_total, np.abs(z).max())
    assert r.stats["object_pixels"] > 0


@pytest.mark.slow
@pytest.mark.parametrize("directions", [1, 16])
def test_each_estimator_is_unbiased_against_mis_of_the_moved_scene(moving, directions):
    """The pixels rendered in full (wavelet against the moved scene) and the others (the static
    image minus the occlusion D, from 1 or 16 stratified directions per camera sample) each
    agree with mis of the moved scene, the ball's hard shadow on the floor among the others."""
    folder, scene, tr = moving
    translate, rotate = (0.4, 0.5, 0.3), [1.0, 1.0, 0.0, 40.0]
    mover = MovingObject(tr, scene, directions=directions)
    r = mover.frame(translate=translate, rotate=rotate, spp=32, seed=6)
    d = scene_dict(translate)
    d["objects"][0]["rotate"] = rotate
    ref = wavlight.render_full(wavlight.load_dict(d, base_dir=folder), spp=1024, strategy="mis", seed=10)
    full = mover._object_pixels(*mover.placement(translate, rotate), 32, 24)
    static = mover.static.mean(2)
    shadow = ~full & (static - ref.image.mean(2) > 4 * ref.stderr.mean(2) + 1e-3)
    assert full.sum() > 20 and shadow.sum() > 20, (full.sum(), shadow.sum())
    diff = r.image.astype(np.float64) - ref.image
    var = r.stderr.astype(np.float64) ** 2 + ref.stderr.astype(np.float64) ** 2
    for name, mask in (("full", full), ("others", ~full), ("shadow", shadow)):
        z = diff[mask].sum() / np.sqrt(var[mask].sum())
        assert abs(z) < 3.3, (name, z)


def test_the_pixels_shaded_in_full_hold_every_view_of_the_object(moving):
    """The conservative cone test marks every pixel whose camera rays can hit the object."""
    folder, scene, tr = moving
    mover = MovingObject(tr, scene)
    R, T = mover.placement([0.9, 0.5, -0.5])
    marked = mover._object_pixels(R, T, 32, 24).reshape(-1)
    moved = wavlight.load_dict(scene_dict((0.9, 0.5, -0.5)), base_dir=folder)
    for corner in ((0.0, 0.0), (1.0, 1.0), (0.0, 1.0), (1.0, 0.0), (0.5, 0.5)):
        py, px = np.mgrid[0:24, 0:32]
        eye, d = wavlight.camera.camera_rays(moved, px.ravel(), py.ravel(), np.tile(corner, (768, 1)), 32, 24)
        prim, _ = wavlight.raytrace.RayTracer(moved.vertices, moved.faces).intersect(eye, d)
        ball = slice(*moved.objects[0].faces_range)
        on_ball = (prim >= ball.start) & (prim < ball.stop)
        assert np.all(marked[on_ball])


def test_command_line_and_the_factors_the_bake_holds_fixed(moving, tmp_path):
    folder, _, _ = moving
    run = lambda *a: CliRunner().invoke(main, [str(x) for x in a])   # noqa: E731
    out = tmp_path / "m.wlt"
    r = run("bake", folder / "scene.toml", "-o", out, "--spp", 2, "--levels", 4, "--terms", 64, "--priority", "area",
            "--vary", "object", "--object", "ball", "--static-spp", 16, "--json")
    assert r.exit_code == 0, r.output
    r = run("frame", out, "--translate", 0.5, 0.5, 0.2, "--spp", 2, "-o", tmp_path / "f.exr", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["frames_per_second"] > 0 and (tmp_path / "f.exr").exists()
    # --repeat means what it means on every bake: the frame of the same state that many times
    r = run("frame", out, "--translate", 0.5, 0.5, 0.2, "--repeat", 3, "-o", tmp_path / "r.exr", "--json")
    assert r.exit_code == 0, r.output
    st = json.loads(r.stdout)
    assert st["frames"] == 3 and st["vary"] == "object" and st["frame"] == "unbiased"
    assert st["frames_per_second"] == pytest.approx(1.0 / st["frame_seconds"], rel=1e-2)
    for args, words in ((("--rotate-y", 30), "varies an object"), (("--env", folder / "sky.exr"), "varies an object")):
        r = run("frame", out, *args, "-o", tmp_path / "g.png")
        assert r.exit_code == 2 and words in r.stderr and not (tmp_path / "g.png").exists(), r.output
    r = run("bake", folder / "scene.toml", "-o", tmp_path / "x.wlt", "--vary", "object", "--object", "cube")
    assert r.exit_code == 2 and "no object 'cube' (objects: 0 (ball), 1)" in r.stderr, r.output
    lit = tmp_path / "lit.wlt"
    assert run("bake", folder / "scene.toml", "-o", lit, "--spp", 1, "--levels", 3, "--terms", 16,
               "--priority", "area").exit_code == 0
    r = run("frame", lit, "--translate", 0, 0, 0, "-o", tmp_path / "h.png")
    assert r.exit_code == 2 and "varies the lighting" in r.stderr, r.output


def test_projection_is_the_inverse_of_the_camera_rays(moving):
    """camera.project puts a point on a sample's ray inside that sample's pixel, at its jitter."""
    _, scene, _ = moving
    rng = np.random.default_rng(3)
    px, py, jitter = rng.integers(0, 32, 500), rng.integers(0, 24, 500), rng.random((500, 2))
    eye, d = wavlight.camera.camera_rays(scene, px, py, jitter, 32, 24)
    xy, depth = wavlight.camera.project(scene.camera, eye + d * rng.uniform(0.5, 8.0, (500, 1)), 32, 24)
    assert np.all(depth > 0)
    np.testing.assert_allclose(xy, np.stack([px + jitter[:, 0], py + jitter[:, 1]], 1), atol=1e-3)


def test_the_pixels_shaded_in_full_are_fewer_than_the_cone_gives(moving):
    """The boxes of the projected triangles leave out pixels the bounding cone holds, and the
    mask holds every pixel a jittered sample of which hits the object (16 samples per pixel)."""
    folder, scene, tr = moving
    mover = MovingObject(tr, scene)
    R, T = mover.placement([0.9, 0.5, -0.5], [0.0, 1.0, 0.0, 30.0])
    marked = mover._object_pixels(R, T, 32, 24).reshape(-1)
    assert marked.sum() <= mover._sphere_pixels(R, T, 32, 24).sum()
    d = scene_dict((0.9, 0.5, -0.5))
    d["objects"][0]["rotate"] = [0.0, 1.0, 0.0, 30.0]
    moved = wavlight.load_dict(d, base_dir=folder)
    py, px = np.mgrid[0:24, 0:32]
    px, py = np.repeat(px.ravel(), 16), np.repeat(py.ravel(), 16)
    eye, d = wavlight.camera.camera_rays(moved, px, py, np.random.default_rng(5).random((len(px), 2)), 32, 24)
    prim, _ = wavlight.raytrace.RayTracer(moved.vertices, moved.faces).intersect(eye, d)
    ball = slice(*moved.objects[0].faces_range)
    on_ball = (prim >= ball.start) & (prim < ball.stop)
    assert on_ball.any() and np.all(marked[(py * 32 + px)[on_ball]])


@pytest.mark.parametrize("material", ["floor", "m", "plastic"])
def test_the_occlusion_kernel_matches_its_numpy_twin(moving, material):
    """kernels/relight_moving.cl moving_occlusion against occlusion_records_reference, on the same
    camera rays and Philox numbers: the floor as it is (lambert) and made ggx (the ball's
    material). float32 against float64 moves a direction across a leaf's or a texel's edge (or
    the box's) now and then: such records are few, and the contributions' sums agree."""
    import dataclasses

    from wavlight.relight import moving as mv

    _, scene, tr = moving
    mover = MovingObject(tr, scene)
    rest = mover.rest
    if material == "plastic":   # the floor made plastic: its coat untinted, both lobes sampled
        from wavlight import bsdfs

        floor = [m.name for m in scene.materials].index("floor")
        rest = dataclasses.replace(rest, materials=[dataclasses.replace(m, kind=bsdfs.PLASTIC, param=0.2)
                                                    if k == floor else m for k, m in enumerate(rest.materials)])
        material = "floor"
    index = [m.name for m in scene.materials].index(material)
    rest = dataclasses.replace(rest, face_material=np.full_like(rest.face_material, index))
    kernels = mv._MovingKernels(rest, mover.rest_tracer, mover.object_tracer, mover.inside, mover._shader, mover.m, 4)
    spp, seed, tile, first = 4, 7, 321, 96
    cam = mover._camera(0, 0, tr.width * tr.height, spp, seed)
    slots = np.flatnonzero(cam.prim >= 0)
    trees, offset = mover._product_trees(0, tr.width * tr.height)
    place, box = mover._place(*mover.placement([0.3, 0.5, 0.2], [0.0, 1.0, 0.0, 30.0]))
    uv = (cam.uv[0][slots], cam.uv[1][slots])
    got = kernels.occlusion(scene.camera.eye, cam.d[slots], cam.prim[slots], cam.t[slots], slots, trees, offset, spp,
                            seed, tile, first, place, box, uv=uv)
    want = mv.occlusion_records_reference(rest, mover.rest_tracer, mover.environment, mover.inside, trees,
                                          cam.d[slots], cam.prim[slots], cam.t[slots], slots, spp, 4, seed, tile,
                                          first, place, box, offset, uv=uv)
    assert len(want.sample) > 200 and abs(len(got.sample) - len(want.sample)) <= 0.01 * len(want.sample)
    # the records of the same sample and direction agree
    common, ig, iw = np.intersect1d(got.sample * 4 + got.j, want.sample * 4 + want.j, return_indices=True)
    assert len(common) > 0.98 * len(want.sample)
    np.testing.assert_allclose(got.origin[ig], want.origin[iw], rtol=0, atol=1e-5)    # shadow-ray origins
    same_dir = np.abs(got.direction[ig] - want.direction[iw]).max(1) < 1e-3
    close = np.abs(got.value[ig] - want.value[iw]).max(1) <= 2e-3 * np.abs(want.value[iw]).max(1) + 1e-6
    assert same_dir.mean() > 0.995 and (same_dir & close).mean() > 0.99, (same_dir.mean(), close.mean())
    assert np.all(np.diff(got.sample // 8) >= 0)    # the work-items' regions in order
    sum_got, sum_want = got.value.sum(0), want.value.sum(0)
    se = want.value.std(0) * np.sqrt(len(want.sample))
    assert np.all(np.abs(sum_got - sum_want) < 0.05 * se + 1e-6), (sum_got, sum_want, se)


def test_the_points_kernel_matches_its_numpy_twin(moving):
    """kernels/relight_moving.cl moving_points against shading_points_reference: the closer of
    the rest's and the object's hits, its normal, the shadow-ray origin, the stratified uniforms,
    the environment for misses and the material, on the same rays and Philox numbers."""
    from wavlight.relight import moving as mv

    _, scene, tr = moving
    mover = MovingObject(tr, scene)
    R, T = mover.placement([0.3, 0.5, 0.2], [0.0, 1.0, 0.0, 30.0])
    spp, seed, tile, first = 8, 11, 77, 16
    cam = mover._camera(0, 0, tr.width * tr.height, spp, seed)
    slots = np.flatnonzero(np.repeat(mover._object_pixels(R, T, tr.width, tr.height).reshape(-1), spp))
    d, prim, t, uv = cam.d[slots], cam.prim[slots], cam.t[slots], (cam.uv[0][slots], cam.uv[1][slots])
    prim_o, t_o, uv_o = mover._trace_object(R, T, scene.camera.eye.astype(np.float32), d, closest=True)
    assert mover.object_tracer.smooth   # the ball's shading normals, in its own frame, turned with it
    place, _ = mover._place(R, T)
    got, got_mat = mover._kernels.points(scene.camera.eye, d, prim, t, prim_o, t_o, slots, place, mover.object.material,
                                         1e-6, spp, seed, tile, first, uv=uv, uv_object=uv_o)
    want, want_mat = mv.shading_points_reference(mover.rest, mover.rest_tracer, mover.object_tracer,
                                                 mover.object.material, mover.environment, d, prim, t, prim_o, t_o, R,
                                                 T, 1e-6, slots, spp, seed, tile, first, uv=uv, uv_object=uv_o)
    on_object = (prim_o >= 0) & ((prim < 0) | (t_o < t))
    assert on_object.sum() > 50 and (~on_object & (prim >= 0)).sum() > 50 and (want_mat < 0).sum() > 0
    np.testing.assert_array_equal(got_mat, want_mat)
    hit = want_mat >= 0
    np.testing.assert_allclose(got[0:6, hit], want[0:6, hit], rtol=0, atol=2e-5)    # normals, origins of hits
    np.testing.assert_allclose(got[13:16, hit], want[13:16, hit], rtol=0, atol=2e-5)  # face normals
    assert np.abs(want[0:3, hit] - want[13:16, hit]).max() > 1e-3                   # shading normals differ
    np.testing.assert_array_equal(got[6:10], want[6:10].astype(np.float32))          # the uniforms, bit for bit
    np.testing.assert_allclose(got[10:13], want[10:13], rtol=1e-6)                   # the environment of misses
    # the uniforms are stratified over each pixel's samples: every cell of the 2 x 4 grid once
    px = slots // spp
    for pixel in np.unique(px)[:20]:
        u = got[6:8, px == pixel]
        cells = np.floor(u[0] * 2).astype(int) + 2 * np.floor(u[1] * 4).astype(int)
        assert sorted(cells) == list(range(8))


def test_the_box_test_never_drops_a_direction_the_object_blocks(moving):
    """Every direction of the twin's mixture that the object blocks (traced against the object
    without any box) is among the records the box test keeps, the twin's and the kernel's (whose
    cone test skips the texels far from the object)."""
    from wavlight.relight import moving as mv

    _, scene, tr = moving
    mover = MovingObject(tr, scene)
    spp, seed, tile = 4, 3, 5
    cam = mover._camera(0, 0, tr.width * tr.height, spp, seed)
    slots = np.flatnonzero(cam.prim >= 0)
    trees, offset = mover._product_trees(0, tr.width * tr.height)
    for translate, rotate in (([0.3, 0.5, 0.2], [0.0, 1.0, 0.0, 30.0]), ([-0.4, 0.3, 0.5], [1.0, 0.0, 1.0, 75.0])):
        R, T = mover.placement(translate, rotate)
        place, box = mover._place(R, T)
        everything = np.float32([-1e6, -1e6, -1e6, 1e6, 1e6, 1e6])
        args = (mover.rest, mover.rest_tracer, mover.environment, mover.inside, trees, cam.d[slots], cam.prim[slots],
                cam.t[slots], slots, spp, 4, seed, tile, 0)
        kept = mv.occlusion_records_reference(*args, place, box, offset)
        every = mv.occlusion_records_reference(*args, place, everything, offset)
        kernel = mover._kernels.occlusion(scene.camera.eye, cam.d[slots], cam.prim[slots], cam.t[slots], slots, trees,
                                          offset, spp, seed, tile, 0, place, box)
        blocked = mover.object_tracer.occluded(every.origin.astype(np.float32), every.direction.astype(np.float32))
        assert blocked.sum() > 100
        wanted = set((every.sample * 4 + every.j)[blocked])
        assert not wanted - set(kept.sample * 4 + kept.j) and len(kept.sample) < 0.8 * len(every.sample)
        assert not wanted - set(kernel.sample * 4 + kernel.j)


@pytest.mark.parametrize("chunks", ["one", "rows", "rows, own trees"])
def test_the_kernel_frame_matches_the_numpy_frame(moving, monkeypatch, chunks):
    """The same frame (same random numbers) with the kernels and with their numpy twins (whose
    trees are each chunk's own); also in chunks of 8 rows, the kernel reading the whole image's
    trees, or each chunk's own (the path of images too large to keep every pixel's tree)."""
    from wavlight.relight import moving as mv

    folder, scene, tr = moving
    if chunks != "one":
        monkeypatch.setattr(mv, "CHUNK_SAMPLES", tr.width * 8 * 8)
    if chunks == "rows, own trees":
        monkeypatch.setattr(mv, "TREE_CACHE_BYTES", 0)
    translate, rotate = (0.9, 0.5, -0.5), [0.0, 1.0, 0.0, 30.0]
    a = MovingObject(tr, scene).frame(translate, rotate, spp=8, seed=5)
    b = MovingObject(tr, scene, backend="numpy").frame(translate, rotate, spp=8, seed=5)
    assert a.stats["object_pixels"] == b.stats["object_pixels"] > 0
    diff = np.abs(a.image - b.image).max(2)
    assert (diff > 1e-3 * (1 + np.abs(b.image).max(2))).mean() < 0.03, diff.max()
    var = (b.stderr ** 2).sum()
    assert abs((a.image - b.image).sum()) < 0.5 * np.sqrt(var)


def test_frames_of_one_seed_share_their_camera_rays(moving):
    """A second frame of the seed and spp reuses the camera rays (and their hits on the rest), and
    gives what a fresh MovingObject gives at that place."""
    _, scene, tr = moving
    mover = MovingObject(tr, scene)
    mover.frame((0.0, 0.5, 0.0), spp=4, seed=3)
    kept = mover._chunks[0]
    mover.frame((0.5, 0.5, 0.0), spp=1, seed=3)          # the viewer's other spp keeps them too
    again = mover.frame((0.9, 0.5, -0.5), spp=4, seed=3)
    assert mover._chunks[0] is kept
    fresh = MovingObject(tr, scene).frame((0.9, 0.5, -0.5), spp=4, seed=3)
    np.testing.assert_array_equal(again.image, fresh.image)
