"""Exports over REST (POST /v1/exports): a scene with a saved design as a variant comes back as a
.glb that the Khronos glTF-Validator accepts, with the approximation report in a header; a
Mitsuba folder as a zip; bad requests are named errors."""
import io
import json
import zipfile

from helpers import validate_gltf

GOLD = {"model": "ggx", "alpha": 0.15, "specular": [0.9, 0.7, 0.3], "albedo": [0.05, 0.04, 0.02]}


def test_export_a_scene_with_a_saved_variant(client, bunny_scene, tmp_path):
    m = client.post("/v1/materials", json={"name": "Gold", "material": GOLD, "scene_id": bunny_scene, "object": "bunny"})
    assert m.status_code == 201, m.text
    r = client.post("/v1/exports", json={"scene_id": bunny_scene, "format": "gltf",
                                         "variants": [{"material_id": m.json()["id"]}]})
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "model/gltf-binary"
    assert r.headers["content-disposition"] == 'attachment; filename="bunny.glb"'
    rep = json.loads(r.headers["x-glint-export-report"])
    assert [x["label"] for x in rep["materials"]] == ["bunny (lambert)", "Gold (bunny, ggx)"]
    assert rep["materials"][1]["rel_rmse"] < 0.08 and rep["bytes"] == len(r.content)
    (tmp_path / "s.glb").write_bytes(r.content)
    v = validate_gltf(tmp_path / "s.glb")
    assert v["issues"]["numErrors"] == 0, v["issues"]["messages"]
    assert "KHR_materials_variants" in v["info"]["extensionsUsed"]

    # a publication's object and variants, by its id
    pub = client.post("/v1/publications", json={"name": "shop", "scene_id": bunny_scene,
                                                "variants": [{"material_id": m.json()["id"], "label": "Gold leaf"}]})
    assert pub.status_code == 201, pub.text
    x = client.post("/v1/exports", json={"publication_id": pub.json()["id"], "format": "mtlx"})
    assert x.status_code == 200 and x.headers["content-type"].startswith("application/xml"), x.text
    assert 'uiname="Gold leaf"' in x.text and "open_pbr_surface" in x.text

    z = client.post("/v1/exports", json={"scene_id": bunny_scene, "format": "mitsuba", "render_check": True})
    assert z.status_code == 200, z.text
    names = zipfile.ZipFile(io.BytesIO(z.content)).namelist()
    assert {"bunny/scene.xml", "bunny/envmap.exr", "bunny/report.json", "bunny/meshes/000-bunny.ply"} <= set(names)
    assert json.loads(z.headers["x-glint-export-report"])["render"][0]["rel_rmse"] < 1e-6   # a Lambert: exact

    bad = client.post("/v1/exports", json={"scene_id": bunny_scene, "format": "gltf", "variants": [{"material_id": "nope"}]})
    assert bad.status_code == 422 and "no material 'nope'" in bad.text
    both = client.post("/v1/exports", json={"scene_id": bunny_scene, "publication_id": "p", "format": "gltf"})
    assert both.status_code == 422 and "exactly one of scene_id and publication_id" in both.text
    assert client.post("/v1/exports", json={"scene_id": "missing", "format": "mtlx"}).status_code == 404
    obj = client.post("/v1/exports", json={"scene_id": bunny_scene, "format": "mtlx", "object": "chair"})
    assert obj.status_code == 422 and "no object 'chair'" in obj.text
    many = client.post("/v1/exports", json={"scene_id": bunny_scene, "format": "gltf",
                                            "variants": [{"material_id": "x"}] * 17})
    assert many.status_code == 422
