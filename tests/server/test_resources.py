"""Resources are returned (issue 9): viewer sessions that end are closed in the database and
leave no memory behind in the workers (many sessions share one copy of a scene's data)."""
import json
import os
from pathlib import Path

from websockets.sync.client import connect


def _rss_mib(pids) -> float:
    total = 0
    for pid in pids:
        try:
            for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1])
        except OSError:
            pass
    return total / 1024


def _children(pid: int) -> list[int]:
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as f:
                    if int(f.read().rsplit(")", 1)[1].split()[1]) == pid:
                        out.append(int(d))
            except (OSError, ValueError, IndexError):
                pass
    return out


def _viewer_round(server, client, pid: str, n: int) -> list[str]:
    ids = []
    for _ in range(n):
        ses = client.post(f"/v1/publications/{pid}/sessions").json()
        with connect(f"ws://127.0.0.1:{server['port']}{ses['stream']}", max_size=None) as ws:
            ws.send(json.dumps({"type": "auth", "token": ses["token"]}))
            while not isinstance(ws.recv(timeout=60), bytes):      # hello, then the first frame
                pass
        ids.append((ses["id"], ses["token"]))
    return ids


def test_viewer_sessions_are_closed_and_memory_is_returned(server, client, bunny_scene):
    m = client.post("/v1/materials", json={"name": "grey", "material": {"model": "lambert"}}).json()
    pub = client.post("/v1/publications", json={"name": "p", "scene_id": bunny_scene,
                                                "variants": [{"material_id": m["id"]}]}).json()
    workers = _children(server["proc"].pid)
    _viewer_round(server, client, pub["id"], 10)            # warm: scene data loaded once
    first = _rss_mib(workers)
    ids = _viewer_round(server, client, pub["id"], 30)
    second = _rss_mib(workers)
    import time
    time.sleep(1.0)
    for sid, tok in ids[-5:]:
        info = client.get(f"/v1/sessions/{sid}", headers={"X-Session-Token": tok}).json()
        assert info["closed"], info
    # 30 more sessions, one after another, must not grow the workers by more than a few MiB each
    growth = second - first
    print(f"worker RSS after 10 viewer sessions {first:.0f} MiB, after 30 more {second:.0f} MiB")
    assert growth < 0.15 * first, f"worker memory grew by {growth:.0f} MiB over 30 closed sessions (from {first:.0f})"
    assert client.get("/healthz").json()["streams"] == 0
