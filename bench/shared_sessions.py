"""A session shared across two ``glint serve`` processes on one SQLite database (sessions shared
across API processes, server/sessions_store.py): how long a change made through one process
takes to reach a tab on the other as a ``peer`` event.

    python bench/shared_sessions.py [--messages N]

Starts two servers (fresh data folders, one database, one blob store), uploads and precomputes
the bunny under the sunset HDRI (tests/.cache/assets, ``glint assets fetch --set test``), opens
one stream on each, then sends N light changes through A, 0.3 s apart, and times each from
its send until B's stream receives it. Prints JSON: n, min/p50/p95/max in ms.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

import httpx  # noqa: E402

from helpers import AssetDir, GlintServer, connect  # noqa: E402  (the test suite's server launcher)


def _bunny(c: httpx.Client, assets) -> str:
    mesh = c.post("/v1/assets/meshes", params={"filename": "bunny.ply"}, content=(assets / "meshes" / "bunny.ply").read_bytes())
    env = c.post("/v1/assets/envmaps", params={"filename": "sunset.exr"}, content=(assets / "env" / "sunset.exr").read_bytes())
    spec = json.loads((ROOT / "tests" / "scenes" / "bunny.json").read_text())
    spec["environment"]["map"] = env.json()["id"]
    spec["objects"][0]["mesh"] = mesh.json()["id"]
    sc = c.post("/v1/scenes", json=spec, params={"name": "bunny"}).json()["id"]
    pre = c.post(f"/v1/scenes/{sc}/precompute").json()["id"]
    while c.get(f"/v1/precomputations/{pre}").json()["status"] not in ("done", "failed"):
        time.sleep(0.5)
    return sc


async def _measure(a, b, ses, n: int) -> list[float]:
    out = []
    async with connect(a.as_dict(), ses["stream"], ses["token"]) as wa, connect(b.as_dict(), ses["stream"], ses["token"]) as wb:
        seq = json.loads(await wa.recv())["state"]["last_seq"]
        await wb.recv()

        async def drain(ws):
            async for _ in ws:
                pass
        da = asyncio.create_task(drain(wa))
        await asyncio.sleep(2.0)
        for i in range(n):
            seq += 1
            want = 10.0 * (i + 1)
            t0 = time.perf_counter()
            await wa.send(json.dumps({"seq": seq, "type": "light", "rotation_deg": want}))
            while True:
                x = await asyncio.wait_for(wb.recv(), 30)
                if isinstance(x, str):
                    ev = json.loads(x)
                    if ev["type"] == "peer" and ev["message"].get("rotation_deg") == want:
                        out.append(1e3 * (time.perf_counter() - t0))
                        break
            await asyncio.sleep(0.3)
        da.cancel()
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--messages", type=int, default=20)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="glint-shared-"))
    env = {"GLINT_DATABASE_URL": f"sqlite:///{tmp / 'shared.db'}"}
    a = GlintServer(tmp / "a", workers=1, env=env)
    b = None
    try:
        with httpx.Client(base_url=a.base, timeout=120) as c:
            scene = _bunny(c, AssetDir())
            ses = c.post("/v1/sessions", json={"scene_id": scene}).json()
        (tmp / "b").mkdir()
        (tmp / "b" / "blobs").symlink_to(tmp / "a" / "blobs", target_is_directory=True)
        b = GlintServer(tmp / "b", workers=1, env=env)
        ms = sorted(asyncio.run(_measure(a, b, ses, args.messages)))
        print(json.dumps({"n": len(ms), "min_ms": round(ms[0], 1), "p50_ms": round(statistics.median(ms), 1),
                          "p95_ms": round(ms[int(0.95 * (len(ms) - 1))], 1), "max_ms": round(ms[-1], 1)}))
    finally:
        if b is not None:
            b.stop()
        a.stop()


if __name__ == "__main__":
    main()
