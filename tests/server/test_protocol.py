"""The session protocol as one typed package (worker/protocol) and the server's session store
(server/sessions_store.py): a message's policy is on its class, so adding a message is one
class; every effect has its worker handler; a session's lock is never dropped while held; and
two stores (two API processes) on one database never lose each other's changes."""
import json
import threading
import typing
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
import pytest
from pydantic import Field

from worker.jobs.runtime import EFFECTS, SessionRuntime
from worker.jobs.scheduling import is_urgent
from worker.protocol import (_MESSAGES, ClientMsg, Effect, Refit, Storage, StrokeEvent, client_msg, message,
                             new_state, stream_schema)
from worker.renderers.cuts import CutRenderer

ROOT = Path(__file__).resolve().parents[2]
SPEC = json.loads((ROOT / "tests" / "scenes" / "bunny.json").read_text())


def test_every_effect_has_one_worker_handler():
    assert set(typing.get_args(Effect)) == set(EFFECTS), set(typing.get_args(Effect)) ^ set(EFFECTS)


def test_policies_are_declared_on_the_message_classes():
    """What the server's and the worker's tables used to say, now each class's own."""
    by = {t: c for t, c in _MESSAGES.items()}
    assert {t for t, c in by.items() if c.storage == "batched"} == {"view", "light", "move", "display", "pick"}
    assert {t for t, c in by.items() if c.storage == "rows"} == {"stroke", "undo", "redo"}
    assert {t for t, c in by.items() if c.urgent} == {"stroke", "undo", "redo", "fit"}
    assert {t for t, c in by.items() if c.drags} == {"view", "light", "move"}
    assert is_urgent({"type": "stroke"}) and not is_urgent({"type": "view"}) and not is_urgent({"type": "nope"})


@pytest.fixture
def tint_message():
    """A stream message defined here, in one class and nowhere else."""
    @message
    class TintMsg(ClientMsg):
        """Test only: exposure by a named step."""
        storage: ClassVar[Storage] = "batched"
        urgent: ClassVar[bool] = True
        readonly_ok: ClassVar[bool] = True
        type: Literal["tint"] = "tint"
        steps: int = Field(ge=-4, le=4)

        def apply(self, st):
            st.exposure = 0.5 * self.steps
            return Refit() if self.steps == 4 else None

    try:
        yield TintMsg
    finally:
        del _MESSAGES["tint"]          # the published schema is the real messages' only


def _db(tmp_path, name="s.db"):
    from server.db import Scene, Session, make_sessionmaker

    db = make_sessionmaker(f"sqlite:///{tmp_path / name}")
    with db() as s, s.begin():
        sc = Scene(name="bunny", spec=SPEC)
        s.add(sc)
        s.flush()
        row = Session(scene_id=sc.id, token_sha256="x", state=new_state(SPEC).model_dump(mode="json"))
        s.add(row)
        s.flush()
        sid = row.id
    return db, sid


def _row(db, sid):
    from server.db import Session

    with db() as s:
        row = s.get(Session, sid)
        return row.state, row.version


def test_a_message_class_is_all_a_new_message_needs(tint_message, tmp_path, bunny_renderer):
    """Validated by the stream's adapter, in the schema, stored as its class says (batched: not
    written before the flush), urgent by its class, and dispatched in the worker."""
    from server.sessions_store import SessionStore

    msg = client_msg.validate_python({"seq": 1, "type": "tint", "steps": 2})
    assert isinstance(msg, tint_message)
    with pytest.raises(Exception):
        client_msg.validate_python({"seq": 1, "type": "tint", "steps": 9})
    assert "TintMsg" in json.dumps(stream_schema()["client_message"])
    assert is_urgent({"type": "tint"})

    db, sid = _db(tmp_path)
    store = SessionStore(db)
    # the first batch of a stream reads the row; a "state" message is written at once
    assert store.persist_batch(sid, [client_msg.validate_python({"seq": 1, "type": "fit"})]) == [
        (None, {"seq": 1, "type": "fit", "constrained": None, "unpainted_weight": None})]
    assert _row(db, sid)[0]["last_seq"] == 1
    [(err, fwd)] = store.persist_batch(sid, [client_msg.validate_python({"seq": 2, "type": "tint", "steps": 2})])
    assert err is None and fwd["type"] == "tint"
    assert _row(db, sid)[0]["exposure"] == 0.0 and store.has_unsaved(sid)      # batched
    store.flush(sid)
    state, version = _row(db, sid)
    assert state["exposure"] == 1.0 and state["last_seq"] == 2 and version == 2
    store.forget(sid)
    assert store.locks_in_use() == 0

    rt = SessionRuntime(bunny_renderer.scene, CutRenderer(bunny_renderer.scene, bunny_renderer.data),
                        {"state": new_state(bunny_renderer.scene.spec).model_dump(mode="json"), "strokes": []})
    assert rt.handle({"seq": 1, "type": "tint", "steps": 4}) == [] and rt.state.exposure == 2.0
    assert rt._needs_fit                       # its Refit effect went through the worker's handler
    hdr, jpeg = rt.frame(1)
    assert hdr["ack"] == 1 and jpeg[:2] == b"\xff\xd8"


def test_a_held_lock_is_never_dropped(tmp_path):
    """Locks of sessions no longer in use go (the table stays small past 10 000 sessions), but
    a lock that is held, or waited for, stays the same lock."""
    from server.sessions_store import SessionStore

    store = SessionStore(db=None)
    holding, release, got = threading.Event(), threading.Event(), threading.Event()

    def holder():
        with store.lock("held"):
            holding.set()
            release.wait(30)

    def waiter():
        with store.lock("held"):
            got.set()

    t = threading.Thread(target=holder)
    t.start()
    holding.wait(10)
    for i in range(10_050):               # past the old clear-everything threshold
        with store.lock(f"s{i}"):
            pass
    assert store.locks_in_use() == 1
    w = threading.Thread(target=waiter)
    w.start()
    assert not got.wait(0.3), "a second thread took a session's lock while it was held"
    release.set()
    assert got.wait(10)
    t.join()
    w.join()
    assert store.locks_in_use() == 0


def test_two_stores_on_one_database_keep_each_others_changes(tmp_path):
    """Two API processes stream one session (each its own store and cache): one moves the
    camera, the other the light, each writing over a row the other has changed since it read
    it. Compare-and-set on the row's version re-applies each one's pending changes over the
    other's: the camera and the light both stay."""
    from server.sessions_store import SessionStore

    db, sid = _db(tmp_path)
    a, b = SessionStore(db), SessionStore(db)
    for i, st in enumerate((a, b)):          # each stream's first batch reads the row
        st.persist_batch(sid, [client_msg.validate_python({"seq": 1 + i, "type": "fit"})])
    a.persist_batch(sid, [client_msg.validate_python({"seq": 10, "type": "view", "eye": [0.3, 0.6, 3.1]})])
    a.flush(sid)
    b.persist_batch(sid, [client_msg.validate_python({"seq": 11, "type": "light", "rotation_deg": 40})])
    b.flush(sid)                              # conflicts with a's write: re-read, light re-applied
    state, version = _row(db, sid)
    assert state["camera"]["eye"] == [0.3, 0.6, 3.1] and state["rotation_deg"] == 40.0, state
    # and the other way round: a's cache is now stale (b wrote last)
    a.persist_batch(sid, [client_msg.validate_python({"seq": 12, "type": "display", "exposure": 1.5})])
    a.forget(sid)
    b.forget(sid)
    state, version2 = _row(db, sid)
    assert (state["camera"]["eye"], state["rotation_deg"], state["exposure"]) == ([0.3, 0.6, 3.1], 40.0, 1.5)
    assert state["last_seq"] == 12 and version2 == version + 1


def test_worker_events_are_applied_by_the_store(tmp_path):
    """A fit is batched like a camera move while a stream is open; a rejected stroke marks its
    row; neither is a raw edit of the stored dict."""
    from server.db import StrokeRow
    from server.sessions_store import SessionStore

    db, sid = _db(tmp_path)
    store = SessionStore(db)
    stroke = {"points": [[62, 62], [88, 64]], "color": [4.0, 4.0, 4.0], "diameter": 10, "kappa": 0.05}
    store.persist_batch(sid, [client_msg.validate_python({"seq": 1, "type": "stroke", "stroke": stroke})])
    mat = {"model": "lambert", "albedo": [0.1, 0.2, 0.3]}
    ev = {"type": "fit", "seq": 1, "object": SPEC["objects"][0]["name"], "material": mat, "curve": {},
          "stats": {"strokes": 1}}
    assert store.apply_worker_event(sid, ev) is ev
    assert _row(db, sid)[0]["materials"][0]["albedo"] == [0.7, 0.7, 0.7]        # batched
    store.flush(sid)
    assert _row(db, sid)[0]["materials"][0]["albedo"] == [0.1, 0.2, 0.3]
    rej = StrokeEvent(seq=1, strokes=0, rejected=True).model_dump()
    assert store.apply_worker_event(sid, rej) == rej
    with db() as s:
        assert [r.rejected for r in s.query(StrokeRow).filter_by(session_id=sid)] == [True]
    store.forget(sid)


def test_a_stroke_painted_on_a_frame_of_another_size_lands_where_it_was_painted():
    """The studio asks for frames at its canvas's size and draws strokes in the pixels of the
    frame it shows, which until the first frame of the new size arrives is the old size: a
    stroke says which (``frame``), and is recorded in the camera's pixels, on the same rays (a
    point scaled by H/h about the image centre, also when the aspect differs)."""
    from worker.fit.brush import Stroke, rescale_stroke
    from worker.scene import Camera

    st = new_state(SPEC)
    cam = st.camera
    W, H = cam.width, cam.height
    full = {"points": [[0.25 * W, 0.5 * H], [0.75 * W, 0.6 * H]], "color": [2.0, 2.0, 2.0], "diameter": 20,
            "kappa": 0.05}
    half = {**full, "points": [[x / 2, y / 2] for x, y in full["points"]], "diameter": 10, "kappa": 0.1}

    def recorded(stroke, frame=None):
        msg = client_msg.validate_python({"seq": 1, "type": "stroke", "stroke": stroke,
                                          **({"frame": frame} if frame else {})})
        return msg.apply(st.model_copy(deep=True)).stroke["stroke"]

    want = recorded(full)
    assert recorded(full, [W, H]) == want
    got = recorded(half, [W // 2, H // 2])          # without the rescale: points at half the place
    assert np.allclose(got["points"], want["points"]) and got["diameter"] == 20 and got["kappa"] == 0.05, got
    # a wider frame of the same height: the same rays, so x shifts about the centre, y stays
    wide = Camera(**{**cam.model_dump(), "width": W + 200})
    moved = rescale_stroke(Stroke.model_validate(full), (W, H), wide)
    assert np.allclose(np.asarray(moved.points), np.asarray(full["points"]) + [100, 0]), moved.points
    assert moved.diameter == 20 and moved.kappa == 0.05
    for bad in ([0, 10], [10], [10, 10, 10], "640x480"):
        with pytest.raises(Exception):
            client_msg.validate_python({"seq": 1, "type": "stroke", "stroke": full, "frame": bad})
