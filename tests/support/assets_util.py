"""Test assets made with trimesh, written where a test asks (tmp_path): a GLB of a floor with an
sRGB base-colour texture of stripes, a metal sphere and (optionally) a non-metal sphere, with or
without vertex normals (:func:`write_designer_glb`: the three parts, low-poly, with normals); an
OBJ + MTL with Kd, Ks, Ns and map_Kd. Nothing binary is checked in.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

#: the stripes' two sRGB colours (8-bit codes) and their count across the floor's texture
STRIPE_A, STRIPE_B = (200, 40, 40), (230, 230, 230)
STRIPES = 8


def stripes_image(width: int = 16, height: int = 8):
    """(height, width, 3) uint8: vertical stripes, one texel wide, alternating A and B."""
    img = np.zeros((height, width, 3), np.uint8)
    img[:, 0::2] = STRIPE_A
    img[:, 1::2] = STRIPE_B
    return img


def floor_mesh(size=4.0, repeat=2.0):
    """A square floor at y = 0 facing +Y, its texture coordinates 0..repeat (the texture repeats)."""
    import trimesh

    h = size / 2
    return trimesh.Trimesh([[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]], [[0, 2, 1], [0, 3, 2]],
                           process=False), np.array([[0, 0], [repeat, 0], [repeat, repeat], [0, repeat]], float)


def sphere_mesh(subdivisions=3, radius=0.5, normals=False):
    """An icosphere; with ``normals`` its vertex normals set to the exact sphere's (the radial
    directions, not trimesh's angle-weighted average of the faces around a vertex)."""
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions, radius)
    if normals:
        mesh.vertex_normals = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    return mesh


def write_glb(path, plastic_sphere=False, camera=False, floor_metallic=1.0, texture=True, subdivisions=3,
              normals=False) -> Path:
    """The GLB: a textured floor (metallicFactor ``floor_metallic``, roughness 0.7), a gold metal
    sphere (metallicFactor 1, roughness 0.3) at x = -0.7 and, with ``plastic_sphere``, a red
    non-metal sphere (metallicFactor 0, roughness 0.4) at x = +0.7; with ``camera`` a glTF
    perspective camera (fov 40 degrees vertical) at (0, 1.5, 5) looking down -Z, tilted. The
    spheres are icospheres of ``subdivisions``; with ``normals`` the file holds their vertex
    normals (glTF ``NORMAL``: the radial directions), else none."""
    import PIL.Image
    import trimesh
    from trimesh.visual.material import PBRMaterial
    from trimesh.visual.texture import TextureVisuals

    floor, uv = floor_mesh()
    floor.visual = TextureVisuals(uv=uv, material=PBRMaterial(
        name="floor", baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=floor_metallic, roughnessFactor=0.7,
        baseColorTexture=PIL.Image.fromarray(stripes_image()) if texture else None))
    gold = sphere_mesh(subdivisions, 0.5, normals)
    gold.visual = TextureVisuals(material=PBRMaterial(name="gold", baseColorFactor=[1.0, 0.78, 0.34, 1.0],
                                                      metallicFactor=1.0, roughnessFactor=0.3))
    scene = trimesh.Scene()
    scene.add_geometry(floor, node_name="floor", geom_name="floor")
    scene.add_geometry(gold, node_name="gold", geom_name="gold",
                       transform=trimesh.transformations.translation_matrix([-0.7, 0.5, 0.0]))
    if plastic_sphere:
        red = sphere_mesh(subdivisions, 0.5, normals)
        red.visual = TextureVisuals(material=PBRMaterial(name="red", baseColorFactor=[0.8, 0.1, 0.1, 1.0],
                                                         metallicFactor=0.0, roughnessFactor=0.4))
        scene.add_geometry(red, node_name="red", geom_name="red",
                           transform=trimesh.transformations.translation_matrix([0.7, 0.5, 0.0]))
    if camera:
        scene.set_camera(angles=(-0.3, 0.0, 0.0), distance=5.0, center=(0.0, 0.0, 0.0), fov=(50.0, 40.0))
    path = Path(path)
    path.write_bytes(scene.export(file_type="glb", include_normals=normals))
    return path


def write_designer_glb(path) -> Path:
    """The GLB of a lighting designer's first try: a floor with an sRGB base-colour texture of
    stripes (a non-metal: plastic), a gold metal sphere and a red non-metal (plastic) sphere,
    both low-poly (320 faces) with per-vertex normals in the file; no camera."""
    return write_glb(path, plastic_sphere=True, floor_metallic=0.0, subdivisions=2, normals=True)


#: a camera on the designer's GLB: both spheres large in the frame, the striped floor behind them
DESIGNER_CAMERA = {"eye": [0.0, 1.1, 2.4], "target": [0.0, 0.4, 0.0], "fov_y": 40.0}


def designer_scene(glb, environment, width, height) -> dict:
    """A scene (for wavlight.load_dict) that names the GLB as ``mesh`` with no material, under
    ``environment``, seen by :data:`DESIGNER_CAMERA`."""
    return {"render": {"width": int(width), "height": int(height)}, "camera": DESIGNER_CAMERA,
            "environment": {"file": str(environment)}, "objects": [{"mesh": str(glb)}]}


MTL = """newmtl tex
Kd 0.8 0.8 0.8
map_Kd stripes.png
newmtl shiny
Kd 0.2 0.3 0.6
Ks 0.5 0.5 0.5
Ns 50
newmtl dull
Kd 0.5 0.4 0.3
"""

OBJ = """mtllib {mtl}
v -1 0 -1
v 1 0 -1
v 1 0 1
v -1 0 1
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
usemtl tex
f 1/1 3/3 2/2
f 1/1 4/4 3/3
usemtl {shiny}
f 1 2 5
f 2 3 5
usemtl dull
f 3 4 5
"""


def write_obj(folder, mtl="a.mtl", write_mtl=True, write_texture=True, shiny="shiny", mtl_text=MTL) -> Path:
    """An OBJ (a textured floor "tex", a Kd+Ks+Ns part "shiny" and a Kd part "dull") with its
    MTL and stripes.png in ``folder``; the MTL or the texture left out on request."""
    import PIL.Image

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "a.obj").write_text(OBJ.format(mtl=mtl, shiny=shiny))
    if write_mtl:
        (folder / mtl).write_text(mtl_text)
    if write_texture:
        PIL.Image.fromarray(stripes_image(8, 4)).save(folder / "stripes.png")
    return folder / "a.obj"
