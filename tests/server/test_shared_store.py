"""Sessions shared across API processes, at the store (server/sessions_store.py): two
SessionStores on one SQLite database stand for two ``glint serve`` processes (the processes
themselves: tests/server/test_two_processes.py). A process that joins waits until the other has
written what it held; from then on each numbers its messages from the database (never one
number twice) and gets the other's messages in seq order, before its own later ones."""
import threading

from sqlalchemy import select

from test_protocol import _db, _row
from worker.protocol import client_msg


def _m(d):
    return client_msg.validate_python(d)


def _logged(db, sid):
    from server.db import SessionLogRow

    with db() as s:
        return [(r.seq, r.origin, r.body["type"]) for r in s.scalars(
            select(SessionLogRow).where(SessionLogRow.session_id == sid).order_by(SessionLogRow.seq))]


def test_two_stores_share_a_session_in_seq_order(tmp_path):
    from server.sessions_store import SessionStore

    db, sid = _db(tmp_path)
    a, b = SessionStore(db), SessionStore(db)
    assert a.announce(sid) == 0                     # alone: no wait, nothing logged
    a.started_at(sid, -1)
    a.persist_batch(sid, [_m({"seq": 0, "type": "fit"})], True)          # the stream's first batch reads the row
    [(err, fwd)] = a.persist_batch(sid, [_m({"seq": 1, "type": "view", "eye": [0.3, 0.6, 3.1]})], True)
    assert err is None and fwd["seq"] == 1
    assert _row(db, sid)[0]["last_seq"] == 0 and _logged(db, sid) == []    # batched, unwritten

    # b joins: it waits until a has seen it, and a writes (and logs) the camera it held first
    joined = {}
    t = threading.Thread(target=lambda: joined.setdefault("n", b.announce(sid)))
    t.start()
    for _ in range(100):
        if a.poll() == [sid]:
            break
    t.join(5)
    assert joined == {"n": 1}
    state = _row(db, sid)[0]
    assert state["last_seq"] == 1 and state["camera"]["eye"] == [0.3, 0.6, 3.1]
    b.started_at(sid, state["last_seq"])            # b's worker session starts from this state
    assert b.take_peers(sid) == []                  # the camera is in it: nothing to forward

    # b's tab numbers from its hello (seq 1 again): the database gives it 2, written at once
    [(err, fwd)] = b.persist_batch(sid, [_m({"seq": 1, "type": "light", "rotation_deg": 40})], True)
    assert err is None and fwd["seq"] == 2
    assert _row(db, sid)[0]["rotation_deg"] == 40.0
    got = a.take_peers(sid)
    assert [(p["seq"], p["type"]) for p in got] == [(2, "light")]
    assert a.take_peers(sid) == []                  # once

    # a, shared now, writes before forwarding too, numbered after b's
    [(err, fwd)] = a.persist_batch(sid, [_m({"seq": 2, "type": "display", "exposure": 1.5})], True)
    assert fwd["seq"] == 3
    # b stores one before it has read a's: a's (3) comes first, then b's own (4)
    [(err, fwd)] = b.persist_batch(sid, [_m({"seq": 2, "type": "light", "rotation_deg": 80})], True)
    assert fwd["seq"] == 4
    assert [(p["seq"], p["type"]) for p in b.take_peers(sid, read=False)] == [(3, "display")]
    assert [p["seq"] for p in a.take_peers(sid)] == [4]
    state = _row(db, sid)[0]
    assert (state["camera"]["eye"], state["rotation_deg"], state["exposure"], state["last_seq"]) == \
        ([0.3, 0.6, 3.1], 80.0, 1.5, 4)
    log = _logged(db, sid)
    # the camera a held when b joined is logged (a's), then every message of both
    assert [x[0] for x in log] == [1, 2, 3, 4] and [x[1] for x in log] == [a.origin, b.origin, a.origin, b.origin]

    # b leaves: a is alone again, batches, and logs nothing more
    b.forget(sid)
    assert a.poll() == []
    a.persist_batch(sid, [_m({"seq": 5, "type": "view", "eye": [0.0, 0.5, 3.0]})], True)
    assert [x[0] for x in _logged(db, sid)] == [1, 2, 3, 4]
    a.forget(sid)
    assert _row(db, sid)[0]["last_seq"] == 5


def test_concurrent_writers_never_share_a_seq(tmp_path):
    """Both stores persist strokes at once from threads: every stroke is stored, each with its
    own seq, and each store's peers are exactly the other's messages, in order."""
    from server.db import StrokeRow
    from server.sessions_store import SessionStore

    db, sid = _db(tmp_path)
    a, b = SessionStore(db), SessionStore(db)
    a.announce(sid)
    a.started_at(sid, -1)
    t = threading.Thread(target=b.announce, args=(sid,))
    t.start()
    while t.is_alive():
        a.poll()
    b.started_at(sid, -1)
    stroke = {"points": [[62, 62], [88, 64]], "color": [4.0, 4.0, 4.0], "diameter": 10, "kappa": 0.05}
    seen = {a.origin: [], b.origin: []}

    def run(store, n):
        for i in range(n):
            [(err, fwd)] = store.persist_batch(sid, [_m({"seq": i + 1, "type": "stroke", "stroke": stroke})], True)
            assert err is None, err
            peers = store.take_peers(sid, read=False)
            seen[store.origin] += [("peer", p["seq"]) for p in peers] + [("mine", fwd["seq"])]

    ts = [threading.Thread(target=run, args=(s, 12)) for s in (a, b)]
    for x in ts:
        x.start()
    for x in ts:
        x.join(60)
    for s in (a, b):
        seen[s.origin] += [("peer", p["seq"]) for p in s.take_peers(sid)]
    with db() as s:
        seqs = [r.seq for r in s.scalars(select(StrokeRow).where(StrokeRow.session_id == sid))]
    assert sorted(seqs) == list(range(1, 25)), seqs
    for origin, got in seen.items():
        order = [q for _, q in got]
        # each process's worker gets all 24, each once, in seq order
        assert order == list(range(1, 25)), (origin, got)
    a.forget(sid)
    b.forget(sid)
