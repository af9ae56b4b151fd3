"""Uploads are read in a child process with a time limit (worker/inspect.py), never in the API
process: a big OBJ or EXR cannot block the server, and one that takes too long is stopped.

Children fork from a forkserver that has the readers imported already, so a check starts in
milliseconds rather than the seconds a fresh interpreter needs.
"""
from __future__ import annotations

import multiprocessing as mp

from fastapi import HTTPException

_ctx = None


def _context():
    global _ctx
    if _ctx is None:
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(["worker.inspect", "worker.scene", "worker.envmap", "trimesh"])
        _ctx = ctx
    return _ctx


def _child(path: str, kind: str, limits: dict, conn) -> None:
    import os

    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    from worker.errors import GlintError
    from worker.inspect import inspect_upload

    try:
        conn.send(("ok", inspect_upload(path, kind, limits)))
    except GlintError as e:
        conn.send(("error", e.status, str(e)))
    except Exception as e:              # a reader's own failure: bad input, explained
        conn.send(("error", 422, f"the upload cannot be read ({type(e).__name__}: {e})"))
    finally:
        conn.close()


def inspect_in_child(path: str, kind: str, limits: dict, seconds: float) -> dict:
    """Run the check (blocking: call it from a thread); HTTPException on bad input or timeout."""
    ctx = _context()
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_child, args=(str(path), kind, limits, child), daemon=True)
    p.start()
    child.close()
    try:
        if not parent.poll(seconds):
            raise HTTPException(422, f"the upload could not be read within {seconds:g} s; it was refused")
        try:
            res = parent.recv()
        except EOFError:
            raise HTTPException(422, f"reading the upload crashed its reader (exit code {p.exitcode})") from None
    finally:
        if p.is_alive():
            p.kill()
        p.join(timeout=5)
        parent.close()
    if res[0] == "ok":
        return res[1]
    raise HTTPException(res[1], res[2])
