"""The service layer (server/services) on its own: plain functions on a database session that
return rows and raise NotFound, Conflict or Invalid, with no HTTP and no server running."""
import pytest

from server.db import make_sessionmaker
from server.services import assets, materials, publications, scenes
from server.services.errors import Conflict, Invalid, NotFound

LAMBERT = {"model": "lambert", "albedo": [0.5, 0.5, 0.5]}


@pytest.fixture
def db(tmp_path):
    S = make_sessionmaker(f"sqlite:///{tmp_path / 'glint.db'}")
    with S() as s:
        yield s


def _scene_body(mesh: str, envmap: str) -> dict:
    return {"version": 1, "environment": {"map": envmap},
            "camera": {"eye": [0, 0.6, 3.2], "target": [0, 0, 0], "width": 160, "height": 120},
            "objects": [{"name": "bunny", "mesh": mesh, "material": LAMBERT}]}


def test_material_versions_and_archiving(db):
    d, v = materials.create(db, "grey", None, None, LAMBERT)
    assert v.version == 1
    _, v2 = materials.save(db, d.id, {**LAMBERT, "albedo": [0.1, 0.2, 0.3]}, "darker")
    db.commit()
    assert v2.version == 2 and materials.get(db, d.id)[1].version == 2
    assert [x.version for x in materials.versions(db, d.id)] == [1, 2]
    assert materials.version(db, d.id, 1).body == LAMBERT
    materials.archive(db, d.id)
    db.commit()
    assert materials.list_designs(db) == [] and len(materials.list_designs(db, include_archived=True)) == 1
    with pytest.raises(Conflict, match="archived"):
        materials.save(db, d.id, LAMBERT)
    with pytest.raises(NotFound, match="no material 'nope'"):
        materials.get(db, "nope")
    with pytest.raises(NotFound, match="has no version 7"):
        materials.version(db, d.id, 7)


def test_scenes_refer_to_uploaded_assets_of_their_kind(db):
    mesh = assets.create(db, "mesh", "dir/bunny.ply", "a" * 64, 10, {})
    env = assets.create(db, "envmap", "sky.exr", "b" * 64, 10, {})
    assert mesh.filename == "bunny.ply" and assets.get(db, mesh.id) is mesh
    with pytest.raises(Invalid, match=r"objects\[0\].mesh: asset .* is a envmap, not a mesh") as e:
        scenes.create(db, "s", _scene_body(env.id, env.id))
    assert e.value.status == 422
    with pytest.raises(Invalid, match="environment.map: 'missing' is not an uploaded asset id"):
        scenes.create(db, "s", _scene_body(mesh.id, "missing"))
    sc = scenes.create(db, "s", _scene_body(mesh.id, env.id))
    db.commit()
    assert scenes.get(db, sc.id).spec["objects"][0]["mesh"] == mesh.id
    assert [x.id for x in scenes.page(db, 10, 0)] == [sc.id]
    p, new = scenes.queue_precomputation(db, sc.id, running=set())
    assert new and p.status == "queued"
    assert scenes.queue_precomputation(db, sc.id, running={p.id}) == (p, False)   # under way: the same one
    with pytest.raises(NotFound, match="no scene 'x'"):
        scenes.queue_precomputation(db, "x", running=set())
    with pytest.raises(NotFound):
        scenes.get_precomputation(db, "x")

    # a publication copies the design's version in and checks what it names
    d, _ = materials.create(db, "grey", sc.id, "bunny", LAMBERT)
    pub = publications.publish(db, "p", sc.id, None, [{"material_id": d.id, "version": None, "label": None}],
                               [{"asset_id": None, "label": "studio", "rotation_deg": 0.0}])
    db.commit()
    assert pub.object == "bunny" and pub.variants[0]["material"] == LAMBERT and pub.environments[0]["asset_id"] == env.id
    assert publications.get(db, pub.id) is pub
    with pytest.raises(Invalid, match=r"variants\[0\]: material .* has no version 3"):
        publications.publish(db, "p", sc.id, None, [{"material_id": d.id, "version": 3, "label": None}], [])
    with pytest.raises(Invalid, match=r"environments\[0\]: .* is not an uploaded environment map"):
        publications.publish(db, "p", sc.id, None, [{"material_id": d.id, "version": None, "label": None}],
                             [{"asset_id": mesh.id, "label": "x", "rotation_deg": 0.0}])


def test_upload_types_and_image_assets(db):
    assert assets.upload_kind("meshes", "Bunny.PLY") == ("mesh", ".ply")
    with pytest.raises(Invalid) as e:
        assets.upload_kind("envmaps", "sky.png")
    assert e.value.status == 415
    img = assets.create(db, "image", "t.npy", "c" * 64, 10, {})
    mesh = assets.create(db, "mesh", "m.obj", "d" * 64, 10, {})
    assert assets.image_file(db, img.id, "target") == {"sha256": "c" * 64, "filename": "t.npy"}
    with pytest.raises(Invalid, match="mask_asset: .* is not an uploaded image asset"):
        assets.image_file(db, mesh.id, "mask")
