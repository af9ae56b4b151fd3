"""Static publications against the real server: a bundle built as a job (turntables of final
frames in the workers), its manifest, content-addressed files with immutable caching and ETags,
the downloadable zip, the rebuild after a republish that renders only what changed, and the
live mode only where the publisher allows it."""
import hashlib
import io
import json
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
SMALL = {"azimuths": 6, "elevations_deg": [20.0, 45.0], "width": 64, "height": 48}
IMMUTABLE = "public, max-age=31536000, immutable"


def upload(client, kind, path):
    r = client.post(f"/v1/assets/{kind}", params={"filename": path.name}, content=path.read_bytes())
    assert r.status_code == 201, r.text
    return r.json()["id"]


@pytest.fixture(scope="module")
def ground_scene(client, shared_assets):
    """(scene id, second envmap id): the bunny standing on a shadow-catching ground
    (tests/scenes/bunny-ground.json) under the beach HDRI, uploaded and precomputed."""
    spec = json.loads((ROOT / "tests" / "scenes" / "bunny-ground.json").read_text())
    spec["environment"]["map"] = upload(client, "envmaps", shared_assets / "env" / "stinson-beach.hdr")
    spec["objects"][0]["mesh"] = upload(client, "meshes", shared_assets / "meshes" / "bunny.ply")
    sunset = upload(client, "envmaps", shared_assets / "env" / "sunset.exr")
    sid = client.post("/v1/scenes", json=spec, params={"name": "bunny on the ground"}).json()["id"]
    pre = client.post(f"/v1/scenes/{sid}/precompute").json()
    for _ in range(600):
        p = client.get(f"/v1/precomputations/{pre['id']}").json()
        if p["status"] in ("done", "failed"):
            break
        time.sleep(0.5)
    assert p["status"] == "done", p
    return sid, sunset


def wait_built(client, pid, timeout=300):
    for _ in range(int(timeout / 0.25)):
        b = client.get(f"/v1/publications/{pid}").json()["bundle"]
        if b["status"] in ("done", "failed"):
            break
        time.sleep(0.25)
    assert b["status"] == "done", b
    return b


def frame(client, name):
    r = client.get(f"/v1/bundle-files/{name}")
    assert r.status_code == 200, r.text
    return r


def test_bundle_manifest_immutable_files_zip_and_incremental_rebuild(server, client, ground_scene):
    sid, sunset = ground_scene
    red = client.post("/v1/materials", json={"name": "Cherry red", "material": {
        "model": "ggx", "alpha": 0.2, "specular": [0.3, 0.3, 0.3], "albedo": [0.6, 0.04, 0.04]}}).json()
    blue = client.post("/v1/materials", json={"name": "Navy", "material": {
        "model": "lambert", "albedo": [0.04, 0.08, 0.5]}}).json()
    body = {"name": "bunny colours", "scene_id": sid, "bundle": SMALL,
            "variants": [{"material_id": red["id"]}, {"material_id": blue["id"]}],
            "environments": [{}, {"asset_id": sunset, "rotation_deg": 90}]}
    r = client.post("/v1/publications", json=body)
    assert r.status_code == 201, r.text
    pub = r.json()
    assert pub["bundle"]["status"] in ("queued", "running", "done") and not pub["live"]
    # the true names of the environments, not a made-up "studio"
    assert [e["label"] for e in pub["environments"]] == ["Stinson beach", "Sunset"]
    b = wait_built(client, pub["id"])
    views = 2 * 2 * 2 * 6
    assert b["stats"]["views"] == views and b["stats"]["rendered"] == views and b["stats"]["reused"] == 0, b

    # the manifest: revalidated (no-cache + ETag, 304 when unchanged); it names every frame
    m = client.get(f"/v1/publications/{pub['id']}/manifest")
    assert m.status_code == 200 and m.headers["cache-control"] == "no-cache", m.headers
    etag = m.headers["etag"]
    assert client.get(f"/v1/publications/{pub['id']}/manifest", headers={"If-None-Match": etag}).status_code == 304
    man = m.json()
    assert man["format"] == "glint-bundle" and man["version"] == 1
    assert (man["width"], man["height"]) == (64, 48) and man["elevations_deg"] == [20.0, 45.0]
    assert len(man["azimuths_deg"]) == 6 and man["ground_shadow"] is True and man["live"] is False
    assert [v["label"] for v in man["variants"]] == ["Cherry red", "Navy"]
    assert [e["label"] for e in man["environments"]] == ["Stinson beach", "Sunset"]
    fr = man["frames"]
    assert (len(fr), len(fr[0]), len(fr[0][0]), len(fr[0][0][0])) == (2, 2, 2, 6)
    # swatches are the colours the variants show on the object: red is red, navy is blue
    sw = [tuple(int(v["swatch"][k:k + 2], 16) for k in (1, 3, 5)) for v in man["variants"]]
    assert sw[0][0] > 1.4 * max(sw[0][1:]) and sw[1][2] > 2 * max(sw[1][:2]), sw

    # files: content-addressed, immutable, ETag and 304
    f = fr[0][0][0][0]
    r1 = frame(client, f["avif1"])
    assert r1.headers["content-type"] == "image/avif" and r1.headers["cache-control"] == IMMUTABLE
    assert hashlib.sha256(r1.content).hexdigest() == f["avif1"].split(".")[0]
    assert r1.headers["etag"] == f'"{f["avif1"].split(".")[0]}"'
    nm = client.get(f"/v1/bundle-files/{f['avif1']}", headers={"If-None-Match": r1.headers["etag"]})
    assert nm.status_code == 304 and nm.content == b"" and nm.headers["cache-control"] == IMMUTABLE
    # again, now from the server's memory (routes/bundle_files.py CachedBundleFiles): the same answers
    again = frame(client, f["avif1"])
    assert again.content == r1.content and all(again.headers[h] == r1.headers[h] for h in
                                                ("etag", "cache-control", "content-type", "content-length"))
    nm = client.get(f"/v1/bundle-files/{f['avif1']}", headers={"If-None-Match": f'"x", {r1.headers["etag"]}'})
    assert nm.status_code == 304 and nm.headers["etag"] == r1.headers["etag"]
    assert client.get(f"/v1/bundle-files/{f['avif1']}", headers={"If-None-Match": '"x"'}).status_code == 200
    im1 = np.asarray(Image.open(io.BytesIO(r1.content)).convert("RGB"), np.float64)
    im2 = np.asarray(Image.open(io.BytesIO(frame(client, f["avif2"]).content)).convert("RGB"), np.float64)
    jp = Image.open(io.BytesIO(frame(client, f["jpeg1"]).content))
    assert im1.shape == (48, 64, 3) and im2.shape == (96, 128, 3) and jp.format == "JPEG" and jp.size == (64, 48)
    assert Image.open(io.BytesIO(r1.content)).format == "AVIF"
    # the 1× frame is the 2× one averaged (up to tone mapping and lossy coding)
    assert np.abs(im2.reshape(48, 2, 64, 2, 3).mean((1, 3)) - im1).mean() < 6
    # turning changes the frame; another variant and another environment change it too
    other = [fr[0][0][0][3], fr[1][0][0][0], fr[0][1][0][0]]
    for g in other:
        img = np.asarray(Image.open(io.BytesIO(frame(client, g["avif1"]).content)).convert("RGB"), np.float64)
        assert np.abs(img - im1).mean() > 2
    # the glTF model of every variant, published beside the frames (for standard viewers and AR)
    glb = frame(client, man["model"]["glb"])
    assert glb.headers["content-type"] == "model/gltf-binary" and glb.headers["cache-control"] == IMMUTABLE
    assert glb.content[:4] == b"glTF" and len(glb.content) == man["model"]["bytes"]
    assert "BRDF RMSE" in man["model"]["summary"]
    # each public file is its blob under its public name (a static server in front serves that folder)
    pub_dir = Path(server["data"]) / "blobs" / "published"
    for name in (f["avif1"], man["model"]["glb"]):
        assert (pub_dir / name).stat().st_ino == (Path(server["data"]) / "blobs" / name[:2] / name.split(".")[0]).stat().st_ino
    # only published files are served: not another blob of the store by its digest, not a bad name
    env_sha = client.get(f"/v1/assets/{sunset}").json()["sha256"]
    assert client.get(f"/v1/bundle-files/{env_sha}.jpg").status_code == 404
    assert client.get("/v1/bundle-files/..%2Fkeys.json").status_code == 404

    # the download: a folder for any static host
    z = client.get(f"/v1/publications/{pub['id']}/bundle.zip")
    assert z.status_code == 200 and z.headers["content-type"] == "application/zip"
    zf = zipfile.ZipFile(io.BytesIO(z.content))
    names = set(zf.namelist())
    assert {"index.html", "player.js", "viewer.css", "manifest.json"} <= names
    files = {n for n in names if n.startswith("files/")}
    assert len(files) == man["files"] == 1 + len({g[k] for per_v in fr for per_e in per_v for per_el in per_e
                                                   for g in per_el for k in ("avif1", "jpeg1", "avif2")})
    assert "files/" + man["model"]["glb"] in files
    assert json.loads(zf.read("manifest.json")) == man
    index = zf.read("index.html").decode()
    assert 'src="player.js"' in index and 'data-files="files/"' in index and 'id="swatches"' in index
    assert zf.read("files/" + f["avif1"]) == r1.content

    # the live mode is the publisher's choice: this one plays its bundle only
    assert client.post(f"/v1/publications/{pub['id']}/sessions").status_code == 403

    # republish after the navy design changed: only the navy frames are rendered again
    client.put(f"/v1/materials/{blue['id']}", json={"material": {"model": "lambert", "albedo": [0.05, 0.3, 0.1]}})
    r = client.put(f"/v1/publications/{pub['id']}", json={**body, "live": True})
    assert r.status_code == 200, r.text
    b2 = wait_built(client, pub["id"])
    assert b2["stats"]["rendered"] == views // 2 and b2["stats"]["reused"] == views // 2, b2["stats"]
    man2 = client.get(f"/v1/publications/{pub['id']}/manifest", headers={"If-None-Match": etag})
    assert man2.status_code == 200 and man2.headers["etag"] != etag
    fr2 = man2.json()["frames"]
    assert fr2[0] == fr[0]                                  # the red frames: the same files
    assert man2.json()["model"]["glb"] != man["model"]["glb"]   # a variant changed: exported again
    assert all(fr2[1][e][el][a] != fr[1][e][el][a] for e in range(2) for el in range(2) for a in range(6))
    assert man2.json()["live"] is True
    assert client.post(f"/v1/publications/{pub['id']}/sessions").status_code == 201
    # publishing it all again with nothing changed renders nothing
    client.put(f"/v1/publications/{pub['id']}", json={**body, "live": True})
    b3 = wait_built(client, pub["id"])
    assert b3["stats"]["rendered"] == 0 and b3["stats"]["reused"] == views, b3["stats"]
    assert b3["stats"]["model"] == b2["stats"]["model"]


def test_bundle_samples_the_renderer_has_no_pattern_for_are_refused(client, ground_scene):
    """3 samples a pixel was accepted and the build failed in the worker (no such pattern): the
    request is refused, naming the field."""
    sid, _ = ground_scene
    mat = client.post("/v1/materials", json={"name": "grey", "material": {"model": "lambert"}}).json()
    r = client.post("/v1/publications", json={"name": "three", "scene_id": sid, "bundle": {**SMALL, "samples": 3},
                                              "variants": [{"material_id": mat["id"]}]})
    assert r.status_code == 422 and "samples" in r.text, r.text


def test_the_scenes_map_is_published_turned_as_the_scene_turns_it(client, ground_scene):
    """The scene turns its map by 90° (what the designer sees in the studio); an environment preset
    that names no rotation shows it the same way, so its frames are those of an explicit 90°
    (the same content keys), not of 0°."""
    sid, _ = ground_scene
    grey = client.post("/v1/materials", json={"name": "Grey", "material": {"model": "lambert",
                                                                          "albedo": [0.5, 0.5, 0.5]}}).json()
    r = client.post("/v1/publications", json={
        "name": "turned", "scene_id": sid, "variants": [{"material_id": grey["id"]}],
        "bundle": {"azimuths": 2, "elevations_deg": [30.0], "width": 32, "height": 24},
        "environments": [{}, {"rotation_deg": 90}, {"rotation_deg": 0}]})
    assert r.status_code == 201, r.text
    assert [e["rotation_deg"] for e in r.json()["environments"]] == [90.0, 90.0, 0.0], r.json()["environments"]
    wait_built(client, r.json()["id"])
    (per_env,) = client.get(f"/v1/publications/{r.json()['id']}/manifest").json()["frames"]
    names = [[f["avif1"] for f in ring] for e in per_env for ring in e]
    assert names[0] == names[1] and names[0] != names[2], names


def test_nginx_in_front_serves_published_files_as_the_service_does(server, client, ground_scene, tmp_path):
    """The static front (server/static_site.py, docker/nginx.conf) serves a bundle's files from
    the published folder with the service's own headers and answers, and passes the viewer page,
    the manifest and everything else to the service."""
    import os
    import shutil
    import socket
    import subprocess

    import httpx

    from helpers import free_port
    from server.static_site import NginxSite, nginx_conf

    assert nginx_conf(NginxSite()) == (ROOT / "docker" / "nginx.conf").read_text(), \
        "docker/nginx.conf is stale: python -m glint nginx-conf --out docker/nginx.conf"
    exe = shutil.which("nginx") or "/usr/sbin/nginx"
    assert os.path.exists(exe), "nginx is missing: apt-get install nginx (scripts/ensure-static, `make static`)"
    sid, sunset = ground_scene
    red = client.post("/v1/materials", json={"name": "Red", "material": {"model": "lambert",
                                                                          "albedo": [0.6, 0.1, 0.1]}}).json()
    r = client.post("/v1/publications", json={"name": "front", "scene_id": sid, "variants": [{"material_id": red["id"]}],
                                              "bundle": {"azimuths": 4, "elevations_deg": [30.0], "width": 32,
                                                         "height": 24}})
    assert r.status_code == 201, r.text
    pid = r.json()["id"]
    wait_built(client, pid)
    man = client.get(f"/v1/publications/{pid}/manifest").json()

    port = free_port()
    run = tmp_path / "nginx"
    run.mkdir()
    conf = run / "nginx.conf"
    conf.write_text(nginx_conf(NginxSite(published=str(Path(server["data"]) / "blobs" / "published"),
                                         web=str(ROOT / "web"), upstream=f"127.0.0.1:{server['port']}",
                                         listen=f"127.0.0.1:{port}", workers="1", run_dir=str(run),
                                         access_log=str(run / "access.log"), error_log=str(run / "error.log"),
                                         user="root" if os.geteuid() == 0 else None)))
    ngx = subprocess.Popen([exe, "-c", str(conf), "-p", str(run), "-e", str(run / "error.log"), "-g", "daemon off;"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(100):
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                assert ngx.poll() is None, (run / "error.log").read_text()
                time.sleep(0.1)
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30) as c:
            f = man["frames"][0][0][0][1]
            for name, media in ((f["avif1"], "image/avif"), (f["jpeg1"], "image/jpeg"), (f["avif2"], "image/avif"),
                                (man["model"]["glb"], "model/gltf-binary")):
                a, b = c.get(f"/v1/bundle-files/{name}"), client.get(f"/v1/bundle-files/{name}")
                assert a.status_code == 200 and a.content == b.content, (name, a.status_code)
                assert a.headers["content-type"] == media and a.headers["cache-control"] == IMMUTABLE
                assert a.headers["etag"] == b.headers["etag"] == f'"{name.split(".")[0]}"'
                assert a.headers["x-content-type-options"] == "nosniff"
                for inm in (a.headers["etag"], "W/" + a.headers["etag"]):
                    nm = c.get(f"/v1/bundle-files/{name}", headers={"If-None-Match": inm})
                    assert nm.status_code == 304 and nm.headers["etag"] == a.headers["etag"], inm
                    assert nm.headers["cache-control"] == IMMUTABLE
                assert c.get(f"/v1/bundle-files/{name}", headers={"If-None-Match": '"0000"'}).status_code == 200
            # only published files: not another blob by its digest, not a bad name
            env_sha = client.get(f"/v1/assets/{sunset}").json()["sha256"]
            assert c.get(f"/v1/bundle-files/{env_sha}.jpg").status_code == 404
            assert c.get("/v1/bundle-files/..%2F..%2Fkeys.json").status_code == 404
            # the page, its scripts and the manifest: the viewer works through the front
            page = c.get(f"/view/{pid}")
            assert page.status_code == 200 and "/web/js/viewer.js" in page.text, page.status_code
            assert c.get("/web/js/player.js").content == (ROOT / "web" / "js" / "player.js").read_bytes()
            mf = c.get(f"/v1/publications/{pid}/manifest")
            assert mf.status_code == 200 and mf.json() == man and mf.headers["cache-control"] == "no-cache"
            # the page and the manifest are held a second by the front: shoppers arriving together
            # cost the service one request, and browsers still revalidate (no-cache)
            hits = [c.get(f"/v1/publications/{pid}/manifest").headers.get("x-cache") for _ in range(3)]
            assert "HIT" in hits, hits
        subprocess.run([exe, "-c", str(conf), "-p", str(run), "-e", str(run / "error.log"), "-s", "reopen"], check=True)
        time.sleep(0.5)
        log = (run / "access.log").read_text().splitlines()
        frames = [line.split(" ") for line in log if "/v1/bundle-files/" in line and " 200 " in line]
        assert frames and all(float(x[3]) >= 0 for x in frames)         # nginx's own time per request
    finally:
        ngx.terminate()
        ngx.wait(timeout=20)


def test_register_links_public_names_to_their_blobs(tmp_path):
    """A public file is its blob under its public name (a hard link a static server can serve);
    the empty markers of older versions are relinked at start-up."""
    import os
    import types

    from server.services.bundle_files import load, register, relink_markers
    from worker.blobs import BlobStore

    st = types.SimpleNamespace(blobs=BlobStore(tmp_path / "blobs"))
    a, b = st.blobs.put(b"frame a" * 100), st.blobs.put(b"frame b" * 100)
    register(st, [f"{a}.avif"])
    pub = tmp_path / "blobs" / "published"
    assert os.path.samefile(pub / f"{a}.avif", st.blobs.path(a)) and (pub / f"{a}.avif").stat().st_mode & 0o004
    assert load(st, f"{a}.avif") == b"frame a" * 100
    (pub / f"{b}.jpg").touch()                       # an older version's empty marker
    assert relink_markers(st) == 1 and (pub / f"{b}.jpg").read_bytes() == b"frame b" * 100
    assert relink_markers(st) == 0
    register(st, [f"{a}.avif"])                      # again: nothing changes
    assert os.path.samefile(pub / f"{a}.avif", st.blobs.path(a))
    with pytest.raises(ValueError):
        register(st, ["../x.avif"])
