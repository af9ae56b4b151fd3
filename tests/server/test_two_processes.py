"""Two ``glint serve`` processes on one database serve one session (a reconnect landing on the
other process, two tabs behind a load balancer): each keeps its own write-behind copy of the
session's state, and writes it compare-and-set on the row's version (server/sessions_store.py),
so neither overwrites what the other changed: a camera moved through one and a light turned
through the other both stay."""
import asyncio
import json
import time
from pathlib import Path

import httpx

from helpers import GlintServer, connect, next_frame

ROOT = Path(__file__).resolve().parents[2]


def _precomputed_bunny(c: httpx.Client, assets) -> str:
    mesh = c.post("/v1/assets/meshes", params={"filename": "bunny.ply"},
                  content=(assets / "meshes" / "bunny.ply").read_bytes())
    env = c.post("/v1/assets/envmaps", params={"filename": "sunset.exr"},
                 content=(assets / "env" / "sunset.exr").read_bytes())
    assert mesh.status_code == 201 and env.status_code == 201, (mesh.text, env.text)
    spec = json.loads((ROOT / "tests" / "scenes" / "bunny.json").read_text())
    spec["environment"]["map"] = env.json()["id"]
    spec["objects"][0]["mesh"] = mesh.json()["id"]
    sc = c.post("/v1/scenes", json=spec, params={"name": "bunny"}).json()["id"]
    pre = c.post(f"/v1/scenes/{sc}/precompute").json()["id"]
    for _ in range(1200):
        p = c.get(f"/v1/precomputations/{pre}").json()
        if p["status"] in ("done", "failed"):
            break
        time.sleep(0.5)
    assert p["status"] == "done", p
    return sc


def test_two_api_processes_on_one_database_keep_each_others_changes(tmp_path, shared_assets):
    db = f"sqlite:///{tmp_path / 'shared.db'}"
    env = {"GLINT_DATABASE_URL": db}
    a_dir, b_dir = tmp_path / "a", tmp_path / "b"
    a = GlintServer(a_dir, workers=1, env=env)
    try:
        with httpx.Client(base_url=a.base, timeout=120) as ca:
            scene = _precomputed_bunny(ca, shared_assets)
            ses = ca.post("/v1/sessions", json={"scene_id": scene}).json()
        # the second process has a data folder of its own, the same database and blob store
        b_dir.mkdir()
        (b_dir / "blobs").symlink_to(a_dir / "blobs", target_is_directory=True)
        b = GlintServer(b_dir, workers=1, env=env)
        try:
            sa, sb = a.as_dict(), b.as_dict()

            async def go():
                async with connect(sa, ses["stream"], ses["token"]) as wa, \
                        connect(sb, ses["stream"], ses["token"]) as wb:
                    ha = json.loads(await wa.recv())
                    hb = json.loads(await wb.recv())
                    assert ha["type"] == hb["type"] == "hello", (ha, hb)
                    seq = max(ha["state"]["last_seq"], hb["state"]["last_seq"])
                    await next_frame(wa)
                    await next_frame(wb)
                    # through A the camera (batched: A writes it within half a second) ...
                    await wa.send(json.dumps({"seq": seq + 1, "type": "view", "eye": [0.3, 0.6, 3.1]}))
                    await next_frame(wa, seq + 1)
                    await asyncio.sleep(1.5)
                    # ... then through B, whose copy still has the old camera, the light
                    await wb.send(json.dumps({"seq": seq + 2, "type": "light", "rotation_deg": 40}))
                    await next_frame(wb, seq + 2)
                    await asyncio.sleep(1.5)
                    # and through A again, whose copy has the old light
                    await wa.send(json.dumps({"seq": seq + 3, "type": "display", "exposure": 1.5}))
                    await next_frame(wa, seq + 3)
                    await asyncio.sleep(1.5)
                return seq

            seq = asyncio.run(go())
            time.sleep(1.0)                   # both streams' ends have written what they held
            for srv in (a, b):
                got = httpx.get(f"{srv.base}/v1/sessions/{ses['id']}", headers={"X-Session-Token": ses["token"]})
                st = got.json()["state"]
                assert st["camera"]["eye"] == [0.3, 0.6, 3.1], st["camera"]
                assert st["rotation_deg"] == 40.0 and st["exposure"] == 1.5, st
                assert st["last_seq"] == seq + 3
        finally:
            b.stop()
    finally:
        a.stop()
