"""A material with painted regions leaves Glint in every format: the glTF splits the object into
one primitive per dominant layer (each bound to its layer's fitted material, for the design and
each variant) and carries the raw weight maps as textures through the mesh's texture coordinates
where it has a layout of its own, else (no coordinates, or a repeating layout) as vertex
attributes, saying why; MaterialX mixes the layers'
OpenPBR shaders by ``geompropvalue`` nodes of the same names; Mitsuba nests ``blendbsdf``s
weighted by the PLY's vertex attributes and renders like Glint's own pixel-mode frame.

Time (2 loaded cores): one glTF fit of the region's GGX (~5 s, shared by the MaterialX test),
two Mitsuba renders of 128 spp at 160×120 (~10 s)."""
import json
import struct

import numpy as np
import pytest

from worker.export.common import ExportError, parse_variants, region_attribute
from worker.export.run import export
from worker.models import GGX, Lambert, Region, Regions

BASE = Lambert(albedo=(0.55, 0.35, 0.2))
GLOSS = GGX(alpha=0.2, specular=(0.8, 0.8, 0.8), albedo=(0.05, 0.05, 0.2))


def _painted(scene) -> Regions:
    """The bunny's right half painted glossy blue, soft-edged over 4 cm (weights 0 … 1)."""
    x = scene.mesh.vertices[:, 0]
    w = np.clip((x - np.median(x)) / 0.04 + 0.5, 0.0, 1.0)
    ids = np.nonzero(w > 0)[0]
    return Regions(base=BASE, vertex_count=len(x),
                   regions=[Region(name="right", material=GLOSS, vertices=ids.tolist(), weights=w[ids].tolist())])


@pytest.fixture(scope="module")
def painted_scene(bunny_renderer):
    from worker.scene import LoadedScene

    sc = bunny_renderer.scene
    spec = sc.spec.model_copy(deep=True)
    spec.objects[0].material = _painted(sc)
    return LoadedScene(spec, sc.root, envmap=sc.envmap)


def _glb_json_and_bin(path):
    data = path.read_bytes()
    n = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + n])
    m = struct.unpack_from("<I", data, 20 + n)[0]
    return doc, data[28 + n:28 + n + m]


def _accessor(doc, blob, i, dtype, width=1):
    acc = doc["accessors"][i]
    view = doc["bufferViews"][acc["bufferView"]]
    a = np.frombuffer(blob, dtype, count=acc["count"] * width, offset=view.get("byteOffset", 0))
    return a.reshape(acc["count"], width) if width > 1 else a


def test_glb_splits_regions_into_primitives_and_keeps_the_weights(painted_scene, bunny_renderer, tmp_path):
    from helpers import validate_gltf

    mat = painted_scene.spec.objects[0].material
    variants = parse_variants(painted_scene, [{"label": "Plain", "materials": {"bunny": {"model": "lambert",
                                                                                         "albedo": [0.5, 0.5, 0.5]}}}])
    out = tmp_path / "painted.glb"
    rep = export(painted_scene, "gltf", out, variants, renderer=bunny_renderer)
    v = validate_gltf(out)
    assert v["issues"]["numErrors"] == 0 and v["issues"]["numWarnings"] == 0, v["issues"]["messages"]
    assert v["info"]["totalTriangleCount"] == len(painted_scene.mesh.faces)
    doc, blob = _glb_json_and_bin(out)
    prims = doc["meshes"][0]["primitives"]
    assert len(prims) == 2, [p["material"] for p in prims]
    names = {m["name"]: i for i, m in enumerate(doc["materials"])}
    base = next(i for n, i in names.items() if "base" in n)
    right = next(i for n, i in names.items() if "right" in n)
    plain = next(i for n, i in names.items() if n.startswith("Plain"))
    assert sorted(p["material"] for p in prims) == sorted([base, right])
    # each primitive's faces are those its layer dominates; the variant binds both to its material
    x = painted_scene.mesh.vertices[:, 0]
    for p in prims:
        faces = _accessor(doc, blob, p["indices"], np.uint16 if len(x) < 65535 else np.uint32).reshape(-1, 3)
        mean_x = x[faces].mean(1)
        med = np.median(x)
        if p["material"] == right:
            assert np.all(mean_x > med - 0.02), mean_x.min() - med
        else:
            assert np.all(mean_x < med + 0.02), mean_x.max() - med
        (mapping,) = p["extensions"]["KHR_materials_variants"]["mappings"]
        assert mapping == {"material": plain, "variants": [0]}
    # the raw weights, as written by the design: the bunny has no texture coordinates, so they are
    # vertex attributes, and the file and the report say why
    (reg,) = doc["meshes"][0]["extras"]["glint"]["regions"]
    attr = region_attribute(mat, 0)
    assert reg["regions"] == [{"region": "right", "attribute": attr, "material_key": reg["regions"][0]["material_key"]}]
    assert reg["storage"] == "vertex attribute" and "no texture coordinates" in reg["why"], reg
    assert rep["regions"] == [{"object": "bunny", "storage": "vertex attribute", "why": reg["why"]}], rep["regions"]
    assert "TEXCOORD_0" not in prims[0]["attributes"] and not doc.get("textures")
    w = _accessor(doc, blob, prims[0]["attributes"][attr], np.float32)
    np.testing.assert_allclose(w, mat.regions[0].dense(len(x)), atol=0)
    # Glint's own render of the exported layers (blended per vertex) against the design
    render = {r["variant"]: r["rel_rmse"] for r in rep["render"]}
    assert render[None] < 0.08, render
    assert render["Plain"] < 0.005, render


@pytest.fixture(scope="module")
def atlas_scene(painted_scene, tmp_path_factory):
    """The painted bunny with a UV atlas (xatlas, as a modeller's unwrap gives one: every face its
    own texels), loaded from an OBJ with ``vt`` like any user's mesh; painted like _painted."""
    xatlas = pytest.importorskip("xatlas")
    from worker.scene import LoadedScene, load_mesh

    src = painted_scene.spec.objects[0].mesh
    m = load_mesh(painted_scene.resolve(src))
    vmap, faces, uvs = xatlas.parametrize(m.vertices, m.faces)
    path = tmp_path_factory.mktemp("atlas") / "bunny-atlas.obj"
    xatlas.export(str(path), m.vertices[vmap], faces, uvs, m.normals[vmap])
    spec = painted_scene.spec.model_copy(deep=True)
    spec.objects[0].mesh = str(path)
    spec.objects[0].material = BASE
    sc = LoadedScene(spec, painted_scene.root, envmap=painted_scene.envmap)
    sc.spec.objects[0].material = _painted(sc)
    return sc


def _bilinear(img, uv):
    """img (S, S) sampled at glTF texture coordinates uv (N, 2) as a GPU does (texel centres at
    half-integers, REPEAT)."""
    s = img.shape[0]
    p = uv * s - 0.5
    x0, y0 = np.floor(p[:, 0]).astype(int), np.floor(p[:, 1]).astype(int)
    fx, fy = p[:, 0] - x0, p[:, 1] - y0
    out = 0.0
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            out = out + img[(y0 + dy) % s, (x0 + dx) % s] * wy * wx
    return out


def test_glb_carries_the_weights_as_textures_through_the_meshs_own_uvs(atlas_scene, tmp_path):
    import io

    from PIL import Image

    from helpers import validate_gltf

    mat = atlas_scene.spec.objects[0].material
    out = tmp_path / "atlas.glb"
    rep = export(atlas_scene, "gltf", out)
    v = validate_gltf(out)
    assert v["issues"]["numErrors"] == 0 and v["issues"]["numWarnings"] == 0, v["issues"]["messages"]
    doc, blob = _glb_json_and_bin(out)
    (reg,) = doc["meshes"][0]["extras"]["glint"]["regions"]
    assert reg["storage"] == "texture", reg
    (r0,) = reg["regions"]
    assert r0["region"] == "right" and r0["texCoord"] == 0, r0
    (info,) = rep["regions"]
    assert info["storage"] == "texture" and info["texture_size"] == 1024, info
    prims = doc["meshes"][0]["primitives"]
    assert len(prims) == 2
    for p in prims:      # no per-vertex copy of the weights: the texture is where they are
        assert "TEXCOORD_0" in p["attributes"] and not [a for a in p["attributes"] if a.startswith("_")], p["attributes"]
    # the texture, decoded from the file, read back where the faces are, against the design's weights
    img = doc["images"][doc["textures"][r0["texture"]]["source"]]
    view = doc["bufferViews"][img["bufferView"]]
    png = blob[view.get("byteOffset", 0):view.get("byteOffset", 0) + view["byteLength"]]
    tex = np.asarray(Image.open(io.BytesIO(png)).convert("L"), np.float64) / 255
    uv = _accessor(doc, blob, prims[0]["attributes"]["TEXCOORD_0"], np.float32, 2).astype(np.float64)
    faces = np.concatenate([_accessor(doc, blob, p["indices"], np.uint16, 1).reshape(-1, 3) for p in prims])
    w = mat.regions[0].dense(mat.vertex_count)
    got = _bilinear(tex, uv[faces].mean(1))
    want = w[faces].mean(1)
    err = np.abs(got - want)
    print(f"weight texture against the design's weights at {len(faces)} face centroids: max {err.max():.4f}, "
          f"mean {err.mean():.5f}; painted faces {(want > 0.5).mean():.1%}")
    assert 0.2 < (want > 0.5).mean() < 0.8                 # both sides of the paint are there
    assert err.max() < 0.02, f"weight texture off by {err.max():.4f} (bound 0.02) at a face centroid"


def test_glb_falls_back_to_vertex_attributes_on_a_repeating_uv_layout(tmp_path):
    """The test table's wood grain repeats (texture coordinates beyond 0…1 on some faces): a
    texture cannot hold a weight per face, so the weights are vertex attributes, and the report
    says why."""
    from helpers import asset_file
    from worker.scene import LoadedScene, parse_scene

    spec = parse_scene({"version": 1, "environment": {"map": str(asset_file("env/sunset.exr"))},
                        "camera": {"eye": [0, 60, 200], "target": [0, 40, 0], "width": 160, "height": 120},
                        "objects": [{"name": "table", "mesh": str(asset_file("meshes/table/table.obj")),
                                     "material": BASE.model_dump(mode="json")}]})
    sc = LoadedScene(spec, tmp_path)
    assert sc.mesh.uvs is not None and not np.isnan(sc.mesh.uvs).any()       # it has coordinates
    sc.spec.objects[0].material = _painted(sc)
    rep = export(sc, "gltf", tmp_path / "table.glb")
    (info,) = rep["regions"]
    assert info["storage"] == "vertex attribute" and "same texels" in info["why"], info
    doc, _ = _glb_json_and_bin(tmp_path / "table.glb")
    assert region_attribute(sc.spec.objects[0].material, 0) in doc["meshes"][0]["primitives"][0]["attributes"]


def test_materialx_mixes_the_layers_by_the_same_weight_maps(painted_scene, tmp_path):
    import MaterialX as mx

    from worker.export.mtlx import libraries

    out = tmp_path / "painted.mtlx"
    export(painted_scene, "mtlx", out)
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(out))
    doc.importLibrary(libraries())
    ok, msg = doc.validate()
    assert ok, msg
    (look,) = doc.getLooks()
    (assign,) = look.getMaterialAssigns()
    surface = doc.getNode(assign.getMaterial()).getInput("surfaceshader").getConnectedNode()
    assert surface.getCategory() == "mix"
    fg, bg = surface.getInput("fg").getConnectedNode(), surface.getInput("bg").getConnectedNode()
    assert fg.getCategory() == bg.getCategory() == "open_pbr_surface"
    assert fg.getInputValue("specular_roughness") < 0.6 < bg.getInputValue("specular_roughness") or \
        bg.getInputValue("specular_weight") < 1e-3, (fg.getInputValue("specular_roughness"), bg.getInputValue("specular_weight"))
    gp = surface.getInput("mix").getConnectedNode()
    assert gp.getCategory() == "geompropvalue"
    assert gp.getInputValue("geomprop") == region_attribute(painted_scene.spec.objects[0].material, 0)


def test_mitsuba_renders_the_regions_like_glint(painted_scene, bunny_renderer, tmp_path):
    """The exported folder (lambert base, ggx region: both exact in Mitsuba) against Glint's pixel
    mode, within the bound of the plain-material folder test (test_formats.py)."""
    mi = pytest.importorskip("mitsuba")
    from scipy.ndimage import binary_erosion

    from worker.renderers import FrameRequest

    out = tmp_path / "mi"
    rep = export(painted_scene, "mitsuba", out, mitsuba_spp=128)
    assert all(m["exact"] for m in rep["materials"]) and len(rep["materials"]) == 2
    assert "blendbsdf" in (out / "scene.xml").read_text() and "mesh_attribute" in (out / "scene.xml").read_text()
    mi.set_variant("scalar_rgb")
    s = mi.load_file(str(out / "scene.xml"))
    a = np.asarray(mi.render(s, seed=1), np.float32)[..., :3]
    b = np.asarray(mi.render(s, seed=2), np.float32)[..., :3]
    ref = 0.5 * (a + b)
    mat = painted_scene.spec.objects[0].material
    ours = bunny_renderer.render(FrameRequest(camera=painted_scene.spec.camera, materials=[mat], shading="pixel"))
    inner = binary_erosion(ours.object_id >= 0, iterations=2)
    norm = np.sqrt((ref[inner] ** 2).mean())
    rel = np.sqrt(((ours.radiance[inner] - ref[inner]) ** 2).mean()) / norm
    noise = 0.5 * np.sqrt(((a[inner] - b[inner]) ** 2).mean()) / norm
    # the region shows: the right half is bluer than the left in both renders
    x = np.arange(ref.shape[1])[None, :].repeat(ref.shape[0], 0)
    cx = np.median(x[inner])
    for img in (ref, ours.radiance):
        left, right = img[inner & (x < cx - 8)], img[inner & (x > cx + 8)]
        assert right[:, 2].mean() / right.sum(1).mean() > left[:, 2].mean() / left.sum(1).mean() + 0.05
    print(f"mitsuba regions folder vs Glint: {rel:.4f} (Mitsuba noise of the mean {noise:.4f})")
    assert rel < 0.08, (rel, noise)
    assert np.sqrt(max(rel ** 2 - noise ** 2, 0)) < 0.05, (rel, noise)


def test_regions_painted_on_another_mesh_are_refused_before_any_fit(painted_scene, tmp_path):
    wrong = _painted(painted_scene).model_copy(update={"vertex_count": len(painted_scene.mesh.vertices) + 1})
    variants = parse_variants(painted_scene, [{"label": "Wrong", "materials": {"bunny": wrong.model_dump(mode="json")}}])
    with pytest.raises(ExportError, match="painted on a mesh of"):
        export(painted_scene, "gltf", tmp_path / "x.glb", variants)
    assert not (tmp_path / "x.glb").exists()
