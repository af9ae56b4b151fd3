"""The three export formats of the test bunny, checked by their own tools: the Khronos
glTF-Validator (npm gltf-validator, tools/), MaterialX's document.validate(), and Mitsuba 3
rendering the exported folder against Glint's render.

Time (2 loaded cores): the three fits of the glTF scene ~20 s together (cached for the MaterialX
test: the same materials), its render check ~10 s at 160×120, two Mitsuba renders of 128 spp
~10 s."""
import json

import numpy as np
import pytest

from worker.export.common import ExportError, parse_variants
from worker.export.run import export
from worker.models import GGX, SRBF

GOLD = {"model": "ggx", "alpha": 0.15, "specular": [0.9, 0.7, 0.3], "albedo": [0.05, 0.04, 0.02]}


@pytest.fixture(scope="module")
def variants(bunny_renderer):
    painted = SRBF.examples()[1].model_dump(mode="json")
    return parse_variants(bunny_renderer.scene, [{"label": "Gold", "materials": {"bunny": GOLD}},
                                                 {"label": "Painted", "materials": {"bunny": painted}}])


def test_glb_with_variants_passes_the_khronos_validator(bunny_renderer, variants, tmp_path):
    import trimesh
    from helpers import validate_gltf

    out = tmp_path / "bunny.glb"
    rep = export(bunny_renderer.scene, "gltf", out, variants, renderer=bunny_renderer)
    v = validate_gltf(out)
    assert v["issues"]["numErrors"] == 0 and v["issues"]["numWarnings"] == 0, v["issues"]["messages"]
    assert v["info"]["totalTriangleCount"] == len(bunny_renderer.scene.mesh.faces)
    assert "KHR_materials_variants" in v["info"]["extensionsUsed"]
    doc = json.loads(out.read_bytes()[20:20 + int.from_bytes(out.read_bytes()[12:16], "little")])
    assert [x["name"] for x in doc["extensions"]["KHR_materials_variants"]["variants"]] == ["Gold", "Painted"]
    maps = doc["meshes"][0]["primitives"][0]["extensions"]["KHR_materials_variants"]["mappings"]
    assert sorted(v for m in maps for v in m["variants"]) == [0, 1] and len({m["material"] for m in maps}) == 2
    assert doc["asset"]["extras"]["glint"]["render"][1]["variant"] == "Gold"
    # the geometry is the scene's, in world space
    tm = trimesh.load(str(out), force="mesh", process=False)
    np.testing.assert_allclose(np.sort(tm.vertices, 0), np.sort(bunny_renderer.scene.mesh.vertices, 0), atol=1e-6)
    # the errors: the Lambert is exact (KHR_materials_specular turns the dielectric's F0 off), the
    # GGX close; the srbf's sharp narrow lobe on a broad one is beyond one GGX lobe (reported)
    mats = {m["label"].split(" ")[0]: m for m in rep["materials"]}
    assert mats["bunny"]["rel_rmse"] < 0.005 and mats["bunny"]["extensions"] == ["KHR_materials_specular"]
    assert mats["Gold"]["rel_rmse"] < 0.08, mats["Gold"]          # measured 5.6%
    assert 0.2 < mats["Painted"]["rel_rmse"] < 0.8                  # measured 59%
    render = {r["variant"]: r["rel_rmse"] for r in rep["render"]}
    assert render[None] < 0.005, render                             # measured 0.0%
    assert render["Gold"] < 0.07, render                            # measured 4.4%
    assert render["Painted"] < 0.25, render                         # measured 17.3%


def test_materialx_openpbr_validates(bunny_renderer, variants, tmp_path):
    import MaterialX as mx

    from worker.export.mtlx import libraries

    out = tmp_path / "bunny.mtlx"
    rep = export(bunny_renderer.scene, "mtlx", out, variants)
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(out))
    doc.importLibrary(libraries())
    ok, msg = doc.validate()
    assert ok, msg
    shaders = [n for n in doc.getNodes() if n.getCategory() == "open_pbr_surface"]
    assert len(shaders) == 3 == len(rep["materials"])
    looks = {lk.getAttribute("uiname"): lk for lk in doc.getLooks()}
    assert set(looks) == {"default", "Gold", "Painted"}
    gold = looks["Gold"].getMaterialAssigns()[0]
    assert gold.getGeom() == "/bunny" and "Gold" in gold.getMaterial()
    # the Gold shader is a metal-like fit of the ggx design
    g = doc.getNode(gold.getMaterial() + "_shader")
    assert g.getInputValue("base_metalness") > 0.5
    # a document that breaks OpenPBR's types is refused by the same validation
    g.getInput("base_color").setType("float")
    assert not doc.validate()[0]


def test_mitsuba_folder_renders_like_glint(bunny_renderer, artifacts, tmp_path):
    """The exported folder rendered by Mitsuba 3 from its scene.xml: against Glint (pixel mode)
    within the accuracy test's bound (tests/test_mitsuba.py), and against Mitsuba's render of the
    same scene built in memory (worker/mitsuba_ref.py) within the noise: the writer loses nothing."""
    mi = pytest.importorskip("mitsuba")
    from scipy.ndimage import binary_erosion

    from worker.mitsuba_ref import render_mitsuba
    from worker.renderers import FrameRequest
    from worker.scene import LoadedScene

    sc = bunny_renderer.scene
    mat = GGX(alpha=0.25, specular=(0.6, 0.5, 0.4), albedo=(0.3, 0.2, 0.1))
    spec = sc.spec.model_copy(deep=True)
    spec.objects[0].material = mat
    scene = LoadedScene(spec, sc.root, envmap=sc.envmap)
    out = tmp_path / "mi"
    rep = export(scene, "mitsuba", out, mitsuba_spp=128)
    assert rep["materials"][0]["exact"] and (out / "meshes").is_dir() and (out / "envmap.exr").is_file()
    mi.set_variant("scalar_rgb")
    s = mi.load_file(str(out / "scene.xml"))
    a = np.asarray(mi.render(s, seed=1), np.float32)[..., :3]
    b = np.asarray(mi.render(s, seed=2), np.float32)[..., :3]
    ref = 0.5 * (a + b)
    ours = bunny_renderer.render(FrameRequest(camera=spec.camera, materials=[mat], shading="pixel"))
    inner = binary_erosion(ours.object_id >= 0, iterations=2)
    norm = np.sqrt((ref[inner] ** 2).mean())
    rel = np.sqrt(((ours.radiance[inner] - ref[inner]) ** 2).mean()) / norm
    noise = 0.5 * np.sqrt(((a[inner] - b[inner]) ** 2).mean()) / norm
    mem = render_mitsuba(scene, spp=128, seed=3)
    rel_mem = np.sqrt(((mem[inner] - ref[inner]) ** 2).mean()) / norm
    print(f"mitsuba folder vs Glint: {rel:.4f} (Mitsuba noise of the mean {noise:.4f}); vs in-memory Mitsuba {rel_mem:.4f}")
    # measured 2026-12-02: 5.7% with Mitsuba's noise 5.2% (2.4% without it); tests/test_mitsuba.py's bound
    assert rel < 0.08, (rel, noise)
    assert np.sqrt(max(rel ** 2 - noise ** 2, 0)) < 0.05, (rel, noise)
    # one 128-spp render against the mean of two: noise √(1 + 1/2)·√2 times that of the mean
    assert rel_mem < 2.5 * noise + 0.005, (rel_mem, noise)


def test_bad_exports_are_clear_errors(bunny_renderer, tmp_path):
    sc = bunny_renderer.scene
    with pytest.raises(ExportError, match="no object 'chair'"):
        parse_variants(sc, [{"label": "x", "materials": {"chair": GOLD}}])
    with pytest.raises(ExportError, match="repeated"):
        parse_variants(sc, [{"label": "x", "materials": {"bunny": GOLD}}, {"label": "x", "materials": {"bunny": GOLD}}])
    with pytest.raises(ExportError, match="unknown export format"):
        export(sc, "usd", tmp_path / "x.usd")
    with pytest.raises(ExportError, match="variants"):
        export(sc, "mitsuba", tmp_path / "m", parse_variants(sc, [{"label": "x", "materials": {"bunny": GOLD}}]))
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    with pytest.raises(ExportError, match="not an earlier Mitsuba export"):
        export(sc, "mitsuba", tmp_path / "busy")
    assert (tmp_path / "busy" / "notes.txt").read_text() == "mine"
    from worker.export import common
    old, common.MAX_FACES = common.MAX_FACES, 100
    try:
        with pytest.raises(ExportError, match="over the export limit of 100"):
            export(sc, "gltf", tmp_path / "big.glb")
    finally:
        common.MAX_FACES = old
    assert not (tmp_path / "big.glb").exists()
