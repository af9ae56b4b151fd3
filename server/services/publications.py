"""Publications: saved designs (variants) and environment presets of one object of a scene, for
the shopper viewer; their static bundles (turntables of final frames, built as a job in the
workers, worker/publish); and the read-only live sessions the viewer may open on them.

A bundle's frames are stored in the blob store under the content keys of their inputs
(worker/publish/keys.py), so a rebuild renders only the views whose key is not stored: after a
republish that changes one variant, that variant's frames alone.
"""
from __future__ import annotations

import asyncio
import json
import logging
import time
import zipfile
from pathlib import Path

from sqlalchemy import select
from starlette.concurrency import run_in_threadpool

from worker.protocol.messages import EnvironmentMsg, VariantMsg, apply
from worker.protocol.state import new_state

from ..db import (
    Asset,
    MaterialDesign,
    MaterialVersion,
    Publication,
    Scene,
    Session,
    latest_version,
    new_id,
    new_secret,
    token_hash,
)
from . import bundle_files
from .errors import Conflict, Invalid, NotFound

log = logging.getLogger("glint")

# the bundle options a publication has when its request names none (docs/guides/publishing.md)
DEFAULT_BUNDLE = {"azimuths": 72, "elevations_deg": None, "width": None, "height": None, "samples": 4,
                  "antialias": "edges", "shading": "refined", "tone": "neutral", "exposure": 0.0, "ground_shadow": None,
                  "encode": {"avif_quality": 60, "avif_quality_2x": 40, "avif_speed": 10, "jpeg_quality": 85}}
MAX_VIEWS = 20_000           # variants × environments × azimuths × elevations of one bundle
# rendered pixels of one bundle (views × its 2× frame): 5.6× the 2 × 2 × 72 × 2 views at 640×480
# a shop's product page needs, so one request cannot occupy the workers for hours
MAX_BUNDLE_PIXELS = 4_000_000_000
BATCH_CAMERAS = 4            # cameras per worker job: small enough to share the work across workers


def env_label(filename: str) -> str:
    """The true name of an environment map from its file name: "studio_small_03.exr" ->
    "Studio small 03"."""
    stem = Path(filename).stem.replace("_", " ").replace("-", " ").strip()
    return (stem[:1].upper() + stem[1:]) if stem else "Environment"


def _resolve(s, scene_id: str, obj: str | None, variants: list[dict], environments: list[dict]):
    sc = s.get(Scene, scene_id)
    if sc is None:
        raise NotFound(f"no scene {scene_id!r}")
    names = [o["name"] for o in sc.spec["objects"]]
    obj = obj or names[0]
    if obj not in names:
        raise Invalid(f"object: no object {obj!r} (objects: {', '.join(names)})")
    out_variants = []
    for i, v in enumerate(variants):
        d = s.get(MaterialDesign, v["material_id"])
        if d is None:
            raise Invalid(f"variants[{i}]: no material {v['material_id']!r}")
        ver = latest_version(s, d.id) if v.get("version") is None else s.scalars(
            select(MaterialVersion).where(MaterialVersion.design_id == d.id, MaterialVersion.version == v["version"])).first()
        if ver is None:
            raise Invalid(f"variants[{i}]: material {v['material_id']!r} has no version {v.get('version')}")
        out_variants.append({"label": v.get("label") or d.name, "material_id": d.id, "version": ver.version,
                             "material": ver.body})
    envs = []
    scene_env = sc.spec["environment"]
    for i, e in enumerate(environments or [{}]):
        aid = e.get("asset_id") or scene_env["map"]
        a = s.get(Asset, aid)
        if a is None or a.kind != "envmap":
            raise Invalid(f"environments[{i}]: {aid!r} is not an uploaded environment map")
        # no rotation named: the scene's own map turned as the scene turns it (what the designer
        # saw in the studio); another map unturned
        rot = e.get("rotation_deg")
        if rot is None:
            rot = scene_env.get("rotation_deg", 0.0) if aid == scene_env["map"] else 0.0
        envs.append({"label": e.get("label") or env_label(a.filename), "asset_id": aid, "rotation_deg": float(rot)})
    return sc, obj, out_variants, envs


def _bundle_options(sc: Scene, bundle: dict | None, n_variants: int, n_envs: int) -> dict:
    """The bundle options with their defaults; Invalid (413) for a bundle over the limits."""
    opts = {**DEFAULT_BUNDLE, **{k: v for k, v in (bundle or {}).items() if v is not None}}
    opts["encode"] = {**DEFAULT_BUNDLE["encode"], **((bundle or {}).get("encode") or {})}
    cam = sc.spec["camera"]
    w, h = opts["width"] or cam["width"], opts["height"] or cam["height"]
    if 2 * w > 8192 or 2 * h > 8192:
        raise Invalid(f"bundle: {w}×{h} frames are over the 4096×4096 limit (their 2× set is rendered at twice that)")
    views = n_variants * n_envs * opts["azimuths"] * len(opts.get("elevations_deg") or [0, 0])
    if views > MAX_VIEWS:
        raise Invalid(f"bundle: {views} views (variants × environments × azimuths × elevations) is over the "
                      f"limit of {MAX_VIEWS}", 413)
    if views * 4 * w * h > MAX_BUNDLE_PIXELS:
        raise Invalid(f"bundle: {views} views of {2 * w}×{2 * h} pixels is over the limit of {MAX_BUNDLE_PIXELS} "
                      "rendered pixels", 413)
    return opts


def publish(s, name: str, scene_id: str, obj: str | None, variants: list[dict], environments: list[dict],
            live: bool = False, bundle: dict | None = None) -> Publication:
    """variants: {material_id, version (None: the latest), label (None: the design's name)};
    environments: {asset_id (None: the scene's map), label (None: the map's name),
    rotation_deg}; live: whether the viewer may open a streaming session; bundle: bundle
    options (DEFAULT_BUNDLE's keys; None: the defaults). The designs' versions are copied in,
    so a later save does not change what shoppers see. NotFound without the scene; Invalid for
    a bad object, design, version or map, named by its place in the request."""
    sc, obj, out_variants, envs = _resolve(s, scene_id, obj, variants, environments)
    p = Publication(name=name, scene_id=sc.id, object=obj, variants=out_variants, environments=envs, live=bool(live),
                    bundle=_bundle_options(sc, bundle, len(out_variants), len(envs)), build=None)
    s.add(p)
    s.flush()
    return p


def republish(s, pub_id: str, name: str, scene_id: str, obj: str | None, variants: list[dict],
              environments: list[dict], live: bool = False, bundle: dict | None = None) -> Publication:
    """Publish again under the same id (so embedded viewers follow): the designs' versions are
    resolved anew (None: the latest). Conflict while a build of it runs."""
    p = get(s, pub_id)
    if p.build and p.build.get("status") in ("queued", "running"):
        raise Conflict(f"publication {pub_id!r} is being built ({p.build.get('progress', 0):.0%}); "
                       "publish again when it is done")
    sc, obj, out_variants, envs = _resolve(s, scene_id, obj, variants, environments)
    p.name, p.scene_id, p.object, p.variants, p.environments = name, sc.id, obj, out_variants, envs
    p.live, p.bundle = bool(live), _bundle_options(sc, bundle, len(out_variants), len(envs))
    return p


def get(s, pub_id: str) -> Publication:
    p = s.get(Publication, pub_id)
    if p is None:
        raise NotFound(f"no publication {pub_id!r}")
    return p


def bundle_state(p: Publication) -> dict:
    """The latest build as the API shows it: {"status": "none" | "queued" | "running" | "done"
    | "failed", "progress", "message", "stats", "manifest": URL of the last finished manifest or
    None}."""
    b = p.build or {}
    sha = b.get("manifest_sha256")
    return {"status": b.get("status", "none"), "progress": float(b.get("progress", 0.0)),
            "message": b.get("message", ""), "stats": b.get("stats") or {},
            "manifest": f"/v1/bundle-files/{sha}.json" if sha else None}


# -- building ------------------------------------------------------------------------------------


def queue_build(s, pub_id: str) -> str:
    """Mark a new build of the publication queued; returns its id (the last finished manifest
    is kept, and served, until the new one is done)."""
    p = get(s, pub_id)
    bid = new_id()
    prev = p.build or {}
    p.build = {"id": bid, "status": "queued", "progress": 0.0, "message": "queued", "stats": {},
               "manifest_sha256": prev.get("manifest_sha256")}
    return bid


def _update(st, pub_id: str, bid: str, **kw) -> None:
    with st.db() as s, s.begin():
        p = s.get(Publication, pub_id)
        if p is None or (p.build or {}).get("id") != bid:
            return                                   # a newer build took over
        p.build = {**(p.build or {}), **kw}


def _prepare(st, pub_id: str) -> tuple[dict, dict]:
    """(the plan with the job's common payload, the manifest's info) of a publication. Blocking."""
    from worker.publish.manifest import plan

    with st.db() as s:
        p = get(s, pub_id)
        try:
            scene = st.scene_payload(s, p.scene_id)
        except (Conflict, NotFound) as e:
            raise Conflict(str(e)) from None
        envs = []
        for e in p.environments:
            a = s.get(Asset, e["asset_id"])
            if a is None:
                raise Conflict(f"environment {e['label']!r}: its map {e['asset_id']!r} is gone")
            envs.append({"sha256": a.sha256, "filename": a.filename, "rotation_deg": e["rotation_deg"],
                         "intensity": scene["spec"]["environment"].get("intensity", 1.0)})
        opts = dict(p.bundle or DEFAULT_BUNDLE)
        ground = opts.get("ground_shadow")
        if ground is None:                 # the scene's: objects standing on its ground cast a shadow
            g = scene["spec"].get("ground")
            ground = bool(g and g.get("shadow", True))
        opts["ground_shadow"] = ground
        variants = [v["material"] for v in p.variants]
        pl = plan(scene, p.object, variants, envs, opts)
        common = {"scene": scene, "object": p.object, "variants": variants, "environments": envs,
                  "render": pl["render"], "encode": pl["encode"]}
        info = {"name": p.name, "publication": p.id, "variants": [v["label"] for v in p.variants],
                "environments": [e["label"] for e in p.environments], "live": p.live, "ground_shadow": ground}
        return {**pl, "common": common}, info


def _stored(st, views: list[dict]) -> tuple[dict, dict, list[dict]]:
    """(files, meta, missing views): what the blob store already holds of each view."""
    from worker.blobs import PartStore
    from worker.publish.keys import FILES, file_key

    parts = PartStore(st.blobs)
    files, meta, missing = {}, {}, []
    for v in views:
        m = parts.get(file_key(v["key"], "meta"))
        if m is None:
            missing.append(v)
            continue
        files[v["key"]] = {n: parts.sha(file_key(v["key"], n)) for n in FILES}
        meta[v["key"]] = json.loads(m)
    return files, meta, missing


def batches(views: list[dict], cameras: int = BATCH_CAMERAS) -> list[list[dict]]:
    """The views in jobs of ``cameras`` cameras each (a camera's views stay together, so its
    primary hits are traced once)."""
    out, cur, cams = [], [], []
    for v in views:
        c = (v["elevation"], v["azimuth"])
        if c not in cams:
            if len(cams) == cameras:
                out.append(cur)
                cur, cams = [], []
            cams.append(c)
        cur.append(v)
    if cur:
        out.append(cur)
    return out


async def run_build(st, pub_id: str, bid: str) -> bool:
    """Background task: build the publication's bundle. The missing views go to the workers in
    batches, as many at once as there are workers (the pool sends each to the least loaded one),
    progress to the database. Returns whether it finished."""
    from worker.publish.manifest import manifest

    t0 = time.perf_counter()
    try:
        await run_in_threadpool(_update, st, pub_id, bid, status="running", message="planning")
        pl, info = await run_in_threadpool(_prepare, st, pub_id)
        files, meta, missing = await run_in_threadpool(_stored, st, pl["views"])
        total, reused = len(pl["views"]), len(pl["views"]) - len(missing)
        jobs = batches(missing)
        done = [0.0] * len(jobs)
        last = [0.0]

        def progress_of(i):
            def on(f, msg):
                done[i] = f * len(jobs[i])
                frac = (reused + sum(done)) / max(1, total)
                if frac - last[0] >= 0.02:
                    last[0] = frac
                    # from the event loop: a short write, done in a thread so the loop never waits
                    asyncio.get_running_loop().run_in_executor(None, lambda: _update(
                        st, pub_id, bid, progress=frac, message=f"{int(reused + sum(done))}/{total} frames"))
            return on

        sem = asyncio.Semaphore(max(1, int(getattr(st.settings, "workers", 1) or 1)))
        rendered, ms = 0, {}

        async def one(i, views):
            nonlocal rendered, reused
            async with sem:
                res = await st.pool.run_job({"type": "bundle_frames", **pl["common"], "views": views},
                                            on_progress=progress_of(i))
            files.update(res["files"])
            meta.update(res["meta"])
            rendered += res["rendered"]
            reused += res.get("skipped", 0)     # stored meanwhile (another build) after the check above
            for k, x in res["ms"].items():
                ms[k] = ms.get(k, 0.0) + x
        # the glTF model is exported beside the frames (one more job for the pool)
        _, model = await asyncio.gather(asyncio.gather(*(one(i, v) for i, v in enumerate(jobs))),
                                        _model(st, pl, info))
        man = manifest(pl, files, meta, {**info, "model": model})
        data = json.dumps(man, separators=(",", ":")).encode()
        sha = await run_in_threadpool(st.blobs.put, data)
        await run_in_threadpool(bundle_files.register, st, _file_names(man) + [f"{sha}.json"])
        stats = {"views": total, "rendered": rendered, "reused": reused, "files": man["files"], "bytes": man["bytes"],
                 "model": model,
                 "manifest_bytes": len(data), "seconds": round(time.perf_counter() - t0, 2), "batches": len(jobs),
                 "ms": {k: round(v, 1) for k, v in ms.items()}}
        await run_in_threadpool(_update, st, pub_id, bid, status="done", progress=1.0, message="done",
                                manifest_sha256=sha, stats=stats)
        log.info("publication %s built: %d views (%d rendered, %d reused), %.1f MB in %.1f s", pub_id, total,
                 rendered, reused, man["bytes"] / 1e6, stats["seconds"])
        return True
    except asyncio.CancelledError:
        await run_in_threadpool(_update, st, pub_id, bid, status="failed", message="cancelled: the server stopped; publish again")
        raise
    except Exception as e:
        log.error("publication %s build failed: %s", pub_id, e)
        await run_in_threadpool(_update, st, pub_id, bid, status="failed", message=str(e)[:1000])
        return False


def _file_names(man: dict) -> list[str]:
    """Every file a manifest names (frames, the model), once each."""
    from worker.publish.keys import FILES

    out = {}
    for per_v in man["frames"]:
        for per_e in per_v:
            for per_el in per_e:
                for f in per_el:
                    for n in FILES:
                        out[f[n]] = None
    if (man.get("model") or {}).get("glb"):
        out[man["model"]["glb"]] = None
    return list(out)


MODEL_FORMAT = 2     # part of the model's content key: bump when the glTF export changes its output


async def _model(st, pl: dict, info: dict) -> dict | None:
    """The published object with every variant as one glTF binary (worker/export, the
    ``KHR_materials_variants`` extension, variants named as the viewer's swatches), for
    standard viewers and AR ("open in your own viewer"): {"glb": file name, "bytes",
    "summary": the approximation's worst errors}, or {"error": message} when the scene cannot
    be exported. Content-keyed like the frames (scene inputs, variants and their labels), so a
    republish exports again only when a variant changed."""
    import hashlib

    from worker.blobs import PartStore
    from worker.publish.keys import scene_inputs

    common = pl["common"]
    scene, obj = common["scene"], common["object"]
    labels = info["variants"]
    key = hashlib.sha256(json.dumps({"glb": MODEL_FORMAT, "labels": labels,
                                     "inputs": [scene_inputs(scene, obj, m) for m in common["variants"]]},
                                    sort_keys=True, separators=(",", ":")).encode()).hexdigest()
    parts = PartStore(st.blobs)
    meta_key = hashlib.sha256(f"{key}/meta".encode()).hexdigest()
    stored = await run_in_threadpool(parts.get, meta_key)
    if stored is not None:
        meta = json.loads(stored)
        if await run_in_threadpool(st.blobs.has, meta["glb"].split(".")[0]):
            return meta
    job = {"type": "export", "scene": scene, "format": "gltf", "render_check": False,
           "variants": [{"label": lab, "materials": {obj: m}} for lab, m in zip(labels, common["variants"])]}
    try:
        res = await st.pool.run_job(job)
    except asyncio.CancelledError:
        raise
    except Exception as e:                   # the bundle is still published; the viewer offers no model
        log.warning("publication %s: no glTF model: %s", info.get("publication"), e)
        return {"error": str(e)[:500]}
    sha = await run_in_threadpool(st.blobs.put, res["bytes"])
    meta = {"glb": f"{sha}.glb", "bytes": len(res["bytes"]), "summary": res["report"].get("summary", "")}
    await run_in_threadpool(parts.put, meta_key, json.dumps(meta).encode())
    return meta


def manifest_sha(s, pub_id: str) -> str:
    """The digest of the publication's current manifest: NotFound without the publication,
    Conflict before its first build is done (the message says how far it is)."""
    p = get(s, pub_id)
    b = p.build or {}
    sha = b.get("manifest_sha256")
    if sha is None:
        if b.get("status") == "failed":
            raise Conflict(f"publication {pub_id!r} has no bundle: its build failed ({b.get('message')})")
        raise Conflict(f"publication {pub_id!r} is being built ({float(b.get('progress', 0.0)):.0%})")
    return sha


# -- the downloadable bundle ---------------------------------------------------------------------

INDEX_HTML = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<link rel="stylesheet" href="viewer.css">
</head>
<body class="viewer" data-manifest="manifest.json" data-files="files/">
{body}
<script type="module" src="player.js"></script>
</body>
</html>
"""


def viewer_body(web_dir: Path) -> str:
    """The shopper viewer's markup (web/viewer.html's <main>), shared by the page the service
    serves and a downloaded bundle's index.html."""
    html = (Path(web_dir) / "viewer.html").read_text()
    a, b = html.index("<main"), html.index("</main>") + len("</main>")
    return html[a:b]


def bundle_zip(st, sha: str) -> Path:
    """A zip of the bundle of manifest ``sha`` for any static host: index.html, player.js (the
    viewer's bundle player), viewer.css, manifest.json and files/<name> for every frame file.
    Stored as a blob (named by the manifest, so it is built once); returns its path. Blocking."""
    import hashlib

    from worker.blobs import PartStore

    parts = PartStore(st.blobs)

    key = hashlib.sha256(f"bundle-zip/1/{sha}".encode()).hexdigest()
    have = parts.sha(key)
    if have is not None and st.blobs.has(have):
        return st.blobs.path(have)
    man = json.loads(st.blobs.get(sha))
    web = Path(st.settings.web_dir)
    tmp = st.blobs.temp_file()
    h = hashlib.sha256()
    try:
        with tmp:
            with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as z:
                # frames are AVIF/JPEG already: storing them compressed again would only cost time
                z.writestr("index.html", INDEX_HTML.format(title=_html_escape(man["name"]), body=viewer_body(web)),
                           compress_type=zipfile.ZIP_DEFLATED)
                z.write(web / "js" / "player.js", "player.js", compress_type=zipfile.ZIP_DEFLATED)
                z.write(web / "css" / "viewer.css", "viewer.css", compress_type=zipfile.ZIP_DEFLATED)
                z.writestr("manifest.json", json.dumps(man, indent=1), compress_type=zipfile.ZIP_DEFLATED)
                for name in _file_names(man):
                    z.writestr("files/" + name, st.blobs.get(name.split(".")[0]))
        with open(tmp.name, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        zsha = st.blobs.put_file(Path(tmp.name), h.hexdigest())
    finally:
        Path(tmp.name).unlink(missing_ok=True)
    parts.adopt(key, zsha)
    return st.blobs.path(zsha)


def _html_escape(s: str) -> str:
    import html

    return html.escape(s, quote=True)


# -- live sessions -------------------------------------------------------------------------------


def viewer_scene(st, s, pub_id: str) -> tuple[Publication, Scene]:
    """The publication and its scene, ready to be viewed live: NotFound without the
    publication, Invalid (403) where the publisher did not allow the live mode, Conflict while
    its scene cannot be viewed (its assets or precomputation missing)."""
    p = get(s, pub_id)
    if not p.live:
        raise Invalid(f"publication {pub_id!r} does not allow the live mode (its publisher can publish it with "
                      "\"live\": true); its bundle plays without a session", 403)
    try:
        st.scene_payload(s, p.scene_id)
    except (Conflict, NotFound) as e:
        raise Conflict(str(e)) from None
    return p, s.get(Scene, p.scene_id)


def open_viewer(s, p: Publication, sc: Scene, client: str) -> tuple[Session, str]:
    """A read-only session on variant 0 under environment preset 0: (its row, its token)."""
    envs = []
    for e in p.environments:
        a = s.get(Asset, e["asset_id"])
        envs.append({"label": e["label"], "sha256": a.sha256, "filename": a.filename, "rotation_deg": e["rotation_deg"]})
    variants = [{"label": v["label"], "material": v["material"]} for v in p.variants]
    state = new_state(sc.spec, p.object, readonly=True, publication=p.id, variants=variants, environments=envs,
                      quality=80)
    state, _ = apply(state, VariantMsg(seq=0, index=0))
    state, _ = apply(state, EnvironmentMsg(seq=0, index=0))
    state.last_seq = -1
    token = new_secret()
    row = Session(scene_id=sc.id, token_sha256=token_hash(token), state=state.model_dump(mode="json"), client=client)
    s.add(row)
    return row, token
