"""Resources are returned: viewer sessions that end are closed in the database and
leave no memory behind in the workers (many sessions share one copy of a scene's data)."""
import json
import os
from pathlib import Path

from helpers import proc_cpu_s
from websockets.sync.client import connect

# a live publication with the smallest bundle: these tests are about its sessions
TINY = {"azimuths": 1, "elevations_deg": [20]}


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


def _quiet(pids, timeout: float = 180.0) -> None:
    """Wait until the processes use under 5% of a core over a second: on the server the suite
    shares, work that earlier tests started (a GI scene's precomputation made in the studio) may
    still run, and its memory is not the sessions'."""
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        c0 = proc_cpu_s(pids)
        time.sleep(1.0)
        if proc_cpu_s(pids) - c0 < 0.05:
            return
    raise AssertionError(f"the workers stayed busy for {timeout:.0f} s")


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
    pub = client.post("/v1/publications", json={"name": "p", "scene_id": bunny_scene, "live": True, "bundle": TINY,
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


def _editing_session(server, client, scene: str, k: int) -> None:
    """A designer: strokes, an orbit (drag), strokes in the new view, then leaves."""
    ses = client.post("/v1/sessions", json={"scene_id": scene}).json()
    with connect(f"ws://127.0.0.1:{server['port']}{ses['stream']}", max_size=None) as ws:
        ws.send(json.dumps({"type": "auth", "token": ses["token"]}))

        def until(seq):
            while True:
                x = ws.recv(timeout=120)
                if isinstance(x, bytes):
                    n = int.from_bytes(x[:4], "big")
                    if json.loads(x[4:4 + n])["ack"] >= seq:
                        return

        until(-1)
        seq = 0
        for j in range(3):
            for i in range(2):
                seq += 1
                y = 50 + 12 * i + 3 * k
                ws.send(json.dumps({"seq": seq, "type": "stroke", "stroke": {
                    "points": [[60, y], [90, y + 2]], "color": [2, 2, 2], "diameter": 8}}))
                until(seq)
            for i in range(10):
                seq += 1
                ws.send(json.dumps({"seq": seq, "type": "view", "eye": [0.05 * (j * 10 + i), 0.6, 3.2], "drag": i < 9}))
            until(seq)


def test_editing_sessions_return_their_memory(server, client, bunny_scene):
    """Eight designers for 30 s, then eight more, grew the workers by ~100 MiB each,
    while Python's allocations stayed flat: freed kernel scratch and session arrays stayed in
    malloc's per-thread arenas. A closed session's memory is now trimmed (runner.py
    release_memory). Rounds of three concurrent editing sessions: after two warm rounds, three
    more may grow the workers by at most 5%."""
    import threading

    workers = _children(server["proc"].pid)

    def round_():
        ts = [threading.Thread(target=_editing_session, args=(server, client, bunny_scene, k)) for k in range(3)]
        for t in ts:
            t.start()
        for t in ts:
            t.join()

    import time

    def ended():
        # every worker session of the rounds closed (a loaded machine ends them later than the
        # clients leave), then a moment for their threads to end and release
        for _ in range(300):
            h = client.get("/healthz").json()
            if h["sessions"] == 0 and h["streams"] == 0:
                break
            time.sleep(0.1)
        else:
            raise AssertionError(f"sessions still open 30 s after their clients left: {h}")
        time.sleep(1.5)
        _quiet(workers)

    _quiet(workers)
    for _ in range(2):                       # warm: the scene's data and the fit's caches fill
        round_()
    ended()
    first = _rss_mib(workers)
    for _ in range(3):
        round_()
    ended()
    second = _rss_mib(workers)
    print(f"worker RSS after two rounds of editing sessions {first:.0f} MiB, after three more {second:.0f} MiB")
    assert second - first < 0.05 * first, \
        f"worker memory grew by {second - first:.0f} MiB over three rounds of closed editing sessions (from {first:.0f})"


def _tracked_after(code: str, tmp_path) -> dict:
    """Run code in a fresh interpreter; report the objects a full collection walks and the
    frozen ones (gc.get_freeze_count) at its end."""
    import subprocess
    import sys

    script = code + "\nimport gc, json\nprint(json.dumps({'walked': len(gc.get_objects()), 'frozen': gc.get_freeze_count()}))\n"
    env = {**os.environ, "GLINT_DATA_DIR": str(tmp_path), "GLINT_DEMO": "false", "GLINT_WORKERS": "1"}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, env=env,
                         cwd=Path(__file__).resolve().parents[2])
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_start_up_objects_are_frozen_out_of_full_collections(tmp_path):
    """A full collection walked every object the imports made, holding the GIL for
    50-170 ms in the server and 40-90 ms in a worker under load (every stream of that process
    stood still). The server's start-up and a worker's start freeze what exists by then; a
    full collection then walks a small fraction of it."""
    worker = _tracked_after("from worker.jobs.runner import _freeze_modules\n_freeze_modules()", tmp_path / "w")
    assert worker["frozen"] > 10 * worker["walked"], worker
    server = _tracked_after(
        "from fastapi.testclient import TestClient\nfrom server.main import create_app\n"
        "c = TestClient(create_app())\nc.__enter__()\nassert c.app.state.glint.pool is not None", tmp_path / "s")
    assert server["frozen"] > 10 * server["walked"], server
