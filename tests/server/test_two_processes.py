"""Two ``glint serve`` processes on one database serve one session (a reconnect landing on the
other process, two tabs behind a load balancer): each keeps its own write-behind copy of the
session's state, and writes it compare-and-set on the row's version (server/sessions_store.py),
so neither overwrites what the other changed: a camera moved through one and a light turned
through the other both stay. And the two tabs see each other's changes live (shared sessions):
each process forwards the other's stored messages to its own worker session, so both draw the
same frame, and to its streams as peer events."""
import asyncio
import json
import time
from pathlib import Path

import httpx
import numpy as np

from helpers import GlintServer, connect
from worker.protocol import decode_frame

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


class Tab:
    """A stream read in the background: its newest frame (header, linear-ish RGB array), how many
    frames came, and its events."""

    def __init__(self, ws):
        self.ws, self.frame, self.frames, self.events = ws, None, 0, []
        self.task = asyncio.create_task(self._read())

    async def _read(self):
        import io

        from PIL import Image

        async for x in self.ws:
            if isinstance(x, bytes):
                hdr, img = decode_frame(x)
                self.frame = (hdr, np.asarray(Image.open(io.BytesIO(img)).convert("RGB"), np.float64))
                self.frames += 1
            else:
                self.events.append(json.loads(x))

    async def until(self, pred, what: str, timeout: float = 30.0):
        t = time.monotonic() + timeout
        while time.monotonic() < t:
            got = pred(self)
            if got:
                return got
            await asyncio.sleep(0.05)
        raise AssertionError(f"no {what} within {timeout} s; events: {[e['type'] for e in self.events][-10:]}")

    def peer(self, kind: str):
        return next((e for e in self.events if e["type"] == "peer" and e["message"]["type"] == kind), None)

    async def settled(self, quiet: float = 1.5, timeout: float = 30.0) -> np.ndarray:
        """The frame once none has come for ``quiet`` s (the anti-aliased still)."""
        t = time.monotonic() + timeout
        while time.monotonic() < t:
            n = self.frames
            await asyncio.sleep(quiet)
            if n == self.frames and self.frame is not None:
                return self.frame[1]
        raise AssertionError(f"frames did not settle within {timeout} s")


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
                    ta, tb = Tab(wa), Tab(wb)
                    fb0 = await tb.settled()
                    # through A the camera (batched: A writes it within half a second) ...
                    await wa.send(json.dumps({"seq": seq + 1, "type": "view", "eye": [0.3, 0.6, 3.1]}))
                    # ... which B's tab is told of, and B's own worker draws
                    peer = await tb.until(lambda t: t.peer("view"), "peer event for A's camera")
                    assert peer["message"]["eye"] == [0.3, 0.6, 3.1], peer
                    fa1, fb1 = await asyncio.gather(ta.settled(), tb.settled())
                    assert np.abs(fb1 - fb0).mean() > 2, "B's frame did not follow A's camera"
                    assert np.abs(fb1 - fa1).mean() < 1, np.abs(fb1 - fa1).mean()
                    # ... then through B, whose copy still has the old camera, the light
                    await wb.send(json.dumps({"seq": seq + 2, "type": "light", "rotation_deg": 40}))
                    peer = await ta.until(lambda t: t.peer("light"), "peer event for B's light")
                    assert peer["message"]["rotation_deg"] == 40, peer
                    fa2, fb2 = await asyncio.gather(ta.settled(), tb.settled())
                    assert np.abs(fa2 - fa1).mean() > 1, "A's frame did not follow B's light"
                    assert np.abs(fb2 - fa2).mean() < 1, np.abs(fb2 - fa2).mean()
                    # and through A again, whose copy has the old light
                    await wa.send(json.dumps({"seq": seq + 3, "type": "display", "exposure": 1.5}))
                    await tb.until(lambda t: t.peer("display"), "peer event for A's exposure")
                    await asyncio.sleep(1.0)
                    # each process numbered the messages in the session: no seq twice
                    seqs = [e["message"]["seq"] for t in (ta, tb) for e in t.events if e["type"] == "peer"]
                    assert sorted(seqs) == [seq + 1, seq + 2, seq + 3], seqs
                    for t in (ta, tb):
                        t.task.cancel()
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
