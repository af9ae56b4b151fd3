"""The worker-side session, without a server: replay after a crash, strokes that cannot apply,
messages already in a restored state, saves re-run after a crash, the per-vertex transfer that
makes stroke frames cheap, and the bound on a fit's size."""
import time

import numpy as np
import pytest

from worker.jobs.curves import brdf_curve
from worker.jobs.runtime import SessionRuntime
from worker.protocol import (NewMaterial, NoEffect, Save, apply, client_msg, decode_frame, encode_frame, new_state,
                             server_event)
from worker.renderers import FrameRequest, Lighting
from worker.renderers.cuts import CutRenderer
from worker.scene import GGX, Lambert

STROKE = {"points": [[62, 62], [88, 64]], "color": [4.0, 4.0, 4.0], "diameter": 10, "kappa": 0.05}


def _stored(scene, **state):
    st = new_state(scene.spec, materials=[Lambert(albedo=(0.4, 0.4, 0.4)).model_dump()],
                   base_material=Lambert(albedo=(0.4, 0.4, 0.4)).model_dump(), **state)
    return st.model_dump(mode="json")


def _runtime(bunny_renderer, strokes=(), **state):
    r = bunny_renderer
    return SessionRuntime(r.scene, CutRenderer(r.scene, r.data), {"state": _stored(r.scene, **state),
                                                                  "strokes": list(strokes)})


def test_stroke_frames_use_the_vertex_transfer_once_built(bunny_renderer):
    """The per-vertex transfer (about a second of one core on a 20K-vertex object) is built in
    the background once a designer paints twice in one view; no frame waits for it."""
    rt = _runtime(bunny_renderer)
    ev = rt.handle({"seq": 1, "type": "stroke", "stroke": STROKE})
    assert ev[0]["type"] == "stroke" and not ev[0]["rejected"]
    ev = rt.fit_if_needed()
    assert ev[0]["type"] == "fit" and ev[0]["stats"]["painted"] > 0
    rt.prefetch()
    assert rt._override() is None and not any(k[0] == "vt" for k in rt._pending)     # one stroke: not wanted
    rt.handle({"seq": 2, "type": "stroke", "stroke": {**STROKE, "points": [[60, 70], [80, 72]]}})
    rt.fit_if_needed()
    assert rt._override() is None               # not built yet: the frame does not wait
    rt.prefetch()
    fut = [f for k, f in rt._pending.items() if k[0] == "vt"][0]
    fut.result(timeout=120)
    ov = rt._override()
    assert ov is not None
    st = rt.state
    req = dict(camera=st.camera, lighting=Lighting(st.rotation_deg, st.intensity), materials=st.materials)
    fast = rt.renderer.render(FrameRequest(**req, vertex_radiance=ov))
    slow = rt.renderer.render(FrameRequest(**req))
    obj = slow.object_id == 0
    a, b = fast.radiance, slow.radiance
    assert np.sqrt(((a - b)[obj] ** 2).mean()) / np.sqrt((b[obj] ** 2).mean()) < 0.02
    # refined (opt-in): the stroke frame's object is refined too, so it stays the settled frame
    fast = rt.renderer.render(FrameRequest(**req, vertex_radiance=ov, shading="refined"))
    slow = rt.renderer.render(FrameRequest(**req, shading="refined"))
    obj = slow.object_id == 0
    a, b = fast.radiance, slow.radiance
    rel = np.sqrt(((a - b)[obj] ** 2).mean()) / np.sqrt((b[obj] ** 2).mean())
    assert rel < 0.02, rel          # exact SRBF sum against the renderer's p(h) table
    # the stroke frame is the settled frame: its object is refined per pixel where the settled
    # one is, although its vertex radiance comes from the transfer
    n_fast, n_slow = fast.info["refined_samples"], slow.info["refined_samples"]
    assert n_slow > 0 and abs(n_fast - n_slow) <= 0.05 * n_slow, (n_fast, n_slow)
    # a view change invalidates it: no override until one is built for the new view
    rt.handle({"seq": 3, "type": "view", "eye": [0.5, 0.6, 3.1]})
    assert rt._override() is None


def test_a_fits_curve_follows_its_frame(bunny_renderer):
    """The studio's curve of a fitted material (its p(h) and lobe evaluated over the plots'
    directions, about as costly as the fit) is sent after the stroke's frame, not before it:
    the fit event carries the material and figures, the curve event follows once."""
    rt = _runtime(bunny_renderer)
    rt.handle({"seq": 1, "type": "stroke", "stroke": STROKE})
    ev = rt.fit_if_needed()
    assert ev[0]["type"] == "fit" and "curve" not in ev[0]
    rt.frame(1)
    after = rt.after_frame()
    m = rt.state.material_of(rt.state.object)
    # (the stroke's highlight falls short under this light: its guidance follows the curve)
    assert [e["type"] for e in after] == ["curve", "guidance"] and after[0]["object"] == rt.state.object
    assert after[0]["curve"] == brdf_curve(m)
    assert rt.after_frame() == []


def test_a_stroke_mid_drag_gets_a_quick_view_completed_after(bunny_renderer):
    """Under load, and for the first stroke after an orbit: a stroke painted in a view not
    built yet is fitted on a quick view (its pixels and a sparse grid, on the drag level's
    cuts); the full view is built in the background once the user stops dragging and replaces
    it, and the design is then exactly what a restore from the stored strokes gives."""
    rt = _runtime(bunny_renderer)
    rt.quick_rows = 40
    woke = []
    rt.wake = lambda: woke.append(1)
    rt.handle({"seq": 1, "type": "view", "eye": [0.3, 0.6, 3.1], "drag": True})
    ev = rt.handle({"seq": 2, "type": "stroke", "stroke": STROKE})
    assert not ev[0]["rejected"], ev
    v = rt.fitter.views[0]
    assert v.partial and v.coarse and v.n < v.n_object / 2, (v.n, v.n_object)
    quick = rt.fit_if_needed()[0]["stats"]
    assert quick["painted"] > 0
    rt.prefetch()
    assert not rt._completions                  # still dragging: nothing built in the background
    rt.handle({"seq": 3, "type": "view", "eye": [0.3, 0.6, 3.1], "drag": False})      # lets go
    rt.prefetch()
    rt.handle({"seq": 4, "type": "display", "exposure": 0.5})     # messages meanwhile keep it coming
    fut = rt._completions[0][2]
    fut.result(timeout=120)
    # the future's done callback (which wakes the session) runs in the builder's thread after
    # result() has returned here: give it a moment
    deadline = time.monotonic() + 10.0
    while not woke and time.monotonic() < deadline:
        time.sleep(0.01)
    assert woke and rt.absorb() and not rt.fitter.views[0].provisional
    full = rt.fit_if_needed()[0]["stats"]
    assert full["pixels"] == v.n_object > quick["pixels"]
    cam = rt.state.camera.model_dump()
    rec = [{"seq": 2, "stroke": STROKE, "camera": cam, "rotation_deg": 0.0, "intensity": 1.0, "undone": False}]
    again = _runtime(bunny_renderer, rec, last_seq=4)
    again.fit_if_needed()
    np.testing.assert_allclose(np.asarray(again.materials[0].coefficients),
                               np.asarray(rt.materials[0].coefficients), rtol=1e-5, atol=1e-8)


def test_a_quick_view_whose_full_build_fails_is_kept_and_the_session_settles(bunny_renderer):
    """A stroke's quick view is built in full in the background; when that build fails (here
    a disk error, in the field a renderer replaced mid-build), it is tried once more, then the
    quick view stays, the studio is told, and the next frames settle. Before, every frame said
    a refit was coming (never settled: the studio showed no final image) and the idle session
    rebuilt the failing view again and again."""
    from worker.jobs.fit_driver import BUILD_TRIES

    rt = _runtime(bunny_renderer)
    rt.quick_rows = 40
    rt.handle({"seq": 1, "type": "view", "eye": [0.3, 0.6, 3.1], "drag": True})
    assert not rt.handle({"seq": 2, "type": "stroke", "stroke": STROKE})[0]["rejected"]
    rt.fit_if_needed()
    rt.handle({"seq": 3, "type": "view", "eye": [0.3, 0.6, 3.1], "drag": False})
    fx = rt.fitter
    real = fx.build_view
    full_builds = []

    def failing(camera, rot, inten, select=None, coarse=False):
        if select is None and not coarse:          # the full build of the quick view
            full_builds.append(1)
            raise OSError("no space left on device")
        return real(camera, rot, inten, select=select, coarse=coarse)

    fx.build_view = failing
    for attempt in range(BUILD_TRIES):
        assert rt.fit_pending(), attempt
        rt.prefetch()
        for _, _, fut in list(rt._completions.values()):
            fut.result(timeout=120)
        changed = rt.absorb()
    assert len(full_builds) == BUILD_TRIES and changed and not rt.fit_pending()
    assert fx.views[0].provisional                  # the quick view is what the strokes fit on
    notes = [e for e in rt.take_events() if e["type"] == "note"]
    assert notes and "could not be built (no space left on device)" in notes[0]["message"], notes
    rt.prefetch()
    assert not rt._completions and len(full_builds) == BUILD_TRIES      # not rebuilt while idle
    hdr, _ = rt.frame(3)
    while rt.needs_still_frame():
        hdr, _ = rt.frame(3)
    assert hdr["settled"], hdr
    fx.build_view = real                            # a new stroke in the view tries the build again
    assert not rt.handle({"seq": 4, "type": "stroke", "stroke": STROKE})[0]["rejected"]
    assert rt.fit_pending()
    _complete_views(rt)                             # built in full this time
    rt.fit_if_needed()
    assert not rt.fit_pending()


def _complete_views(rt):
    """Wait for the background builds of the session's quick views and take them."""
    rt.prefetch()
    for _, _, fut in list(rt._completions.values()):
        fut.result(timeout=120)
    rt.absorb()
    assert not any(v.provisional for v in rt.fitter.views)


def test_a_reopened_session_draws_before_it_replays_its_strokes(bunny_renderer):
    """A reload's first frame shows the stored material (the strokes' fit) without waiting for
    the replay of the strokes, which builds each view's fit rows (seconds at a studio canvas's
    size); the first message replays them before it applies, so an undo undoes the stroke."""
    rt = _runtime(bunny_renderer)
    rt.handle({"seq": 1, "type": "stroke", "stroke": STROKE})
    rt.fit_if_needed()
    fitted = rt.materials[0]
    cam = rt.state.camera.model_dump()
    rec = [{"seq": 1, "stroke": STROKE, "camera": cam, "rotation_deg": 0.0, "intensity": 1.0, "undone": False}]
    stored = rt.state.model_dump(mode="json")
    again = SessionRuntime(rt.scene, CutRenderer(rt.scene, rt.renderer.data), {"state": stored, "strokes": rec})
    assert again.fitter is None                  # nothing replayed yet
    assert again.materials[0] == fitted
    hdr, jpeg = again.frame(1)
    assert hdr["ack"] == 1 and again.fitter is None
    again.handle({"seq": 2, "type": "undo"})
    assert again.fitter is not None and len(again.fitter.history) == 0 and again.fitter.history.can_redo
    ev = again.fit_if_needed()
    assert ev[0]["stats"]["strokes"] == 0        # back to the base material


def test_replay_rebuilds_the_same_design(bunny_renderer):
    rt = _runtime(bunny_renderer)
    rt.handle({"seq": 1, "type": "stroke", "stroke": STROKE})
    rt.handle({"seq": 2, "type": "light", "rotation_deg": 40})
    second = {**STROKE, "points": [[50, 80], [70, 82]], "color": [-1, -1, -1]}
    rt.handle({"seq": 3, "type": "stroke", "stroke": second})
    rt.handle({"seq": 4, "type": "undo"})
    _complete_views(rt)             # live strokes got quick views; the full ones replace them
    rt.fit_if_needed()
    a = np.asarray(rt.materials[0].coefficients)
    # what the server persists: each stroke with the view and light it was painted in, and its flag
    cam = rt.state.camera.model_dump()
    recs = [{"seq": 1, "stroke": STROKE, "camera": cam, "rotation_deg": 0.0, "intensity": 1.0, "undone": False},
            {"seq": 3, "stroke": second, "camera": cam, "rotation_deg": 40.0, "intensity": 1.0, "undone": True}]
    again = _runtime(bunny_renderer, recs, rotation_deg=40.0, last_seq=4)
    again.fit_if_needed()
    np.testing.assert_allclose(np.asarray(again.materials[0].coefficients), a, rtol=1e-6, atol=1e-9)
    # the undone stroke is on the redo stack, not active
    assert again.fitter.history.can_redo and len(again.fitter.history) == 1
    again.handle({"seq": 5, "type": "redo"})
    assert len(again.fitter.history) == 2


def test_a_stroke_that_cannot_apply_is_rejected_and_the_session_reopens(bunny_renderer):
    """One bad stroke must not break a session for good. A stroke painted while the
    object is off screen is rejected (reported with its seq, so the server stops replaying it);
    a stored one that fails on replay is rejected too, and the session still opens."""
    rt = _runtime(bunny_renderer)
    rt.handle({"seq": 1, "type": "view", "eye": [0, 0, -3], "target": [0, 0, -6]})      # looking away
    ev = rt.handle({"seq": 2, "type": "stroke", "stroke": STROKE})
    assert ev[0]["rejected"] and ev[0]["seq"] == 2 and "covers no pixel" in ev[0]["notes"][0], ev
    hdr, jpeg = rt.frame(2)                    # the session goes on
    assert hdr["ack"] == 2 and jpeg[:2] == b"\xff\xd8"
    # the same stroke stored and replayed on a new worker: rejected again, never fatal
    away = rt.state.camera.model_dump()
    recs = [{"seq": 2, "stroke": STROKE, "camera": away, "rotation_deg": 0.0, "intensity": 1.0, "undone": False}]
    again = _runtime(bunny_renderer, recs, last_seq=2)
    assert again.frame(2)[0]["ack"] == 2
    evs = again.fit_if_needed() + again.take_events()      # the replay (before the first fit)
    assert any(e["type"] == "stroke" and e["rejected"] and e["seq"] == 2 for e in evs), evs


def test_a_stored_material_over_todays_limits_does_not_block_restores(bunny_renderer):
    """A persisted oversize material must not make restores fail forever."""
    r = bunny_renderer
    stored = _stored(r.scene)
    n = 5000                                    # over srbf's 4,096 centres
    stored["materials"] = [{"model": "srbf", "centers": [[0, 0, 1]] * n, "bandwidth": 80.0,
                            "coefficients": [[0.1, 0.1, 0.1]] * n}]
    rt = SessionRuntime(r.scene, CutRenderer(r.scene, r.data), {"state": stored, "strokes": []})
    notes = [e["message"] for e in rt.take_events() if e["type"] == "note"]
    assert any("not valid any more" in m for m in notes), notes
    assert rt.materials[0].model == "lambert"
    assert rt.frame(0)[1][:2] == b"\xff\xd8"


def test_messages_already_in_the_restored_state_are_skipped(bunny_renderer):
    """The restore race: a stroke persisted before the restore read the state arrives
    again as a message; it must not be applied twice."""
    rec = {"seq": 7, "stroke": STROKE, "camera": None, "rotation_deg": 0.0, "intensity": 1.0, "undone": False}
    r = bunny_renderer
    rec["camera"] = r.scene.spec.camera.model_dump()
    rt = _runtime(r, [rec], last_seq=7)
    rt.replay_stored()                 # (the first message or fit would)
    assert len(rt.fitter.history) == 1
    assert rt.handle({"seq": 7, "type": "stroke", "stroke": STROKE}) == []
    assert len(rt.fitter.history) == 1
    rt.handle({"seq": 8, "type": "stroke", "stroke": STROKE})
    assert len(rt.fitter.history) == 2


def test_a_pending_save_is_run_again_after_a_restore(bunny_renderer):
    """A save in flight when the worker died is in the stored state; the new worker
    asks the server to store it (the server's unique (session, seq) stores it once)."""
    rt = _runtime(bunny_renderer, pending_saves=[{"seq": 3, "name": "shiny"}], last_seq=3)
    evs = rt.take_events()
    saves = [e for e in evs if e["type"] == "save"]
    assert len(saves) == 1 and saves[0]["seq"] == 3 and saves[0]["name"] == "shiny"
    assert saves[0]["material"]["model"] == "lambert"
    assert not [e for e in rt.take_events() if e["type"] == "save"]       # once


def test_one_apply_for_server_and_worker():
    """The state the server stores and the one the worker renders come from the same apply."""
    from worker.scene import parse_scene

    spec = parse_scene({"environment": {"map": "m"}, "camera": {"eye": [0, 0, 3], "target": [0, 0, 0]},
                        "objects": [{"name": "a", "mesh": "x"}, {"name": "b", "mesh": "y"}]})
    st = new_state(spec)
    msgs = [{"seq": 1, "type": "view", "eye": [1, 0, 3]}, {"seq": 2, "type": "light", "rotation_deg": 30},
            {"seq": 3, "type": "material", "object": "b", "material": GGX(alpha=0.1).model_dump()},
            {"seq": 4, "type": "material", "material": GGX(alpha=0.3).model_dump()},
            {"seq": 5, "type": "display", "exposure": 1.0}, {"seq": 6, "type": "save", "name": "x"}]
    effects = []
    for m in msgs:
        st, eff = apply(st, client_msg.validate_python(m))
        effects.append(eff)
    assert st.camera.eye == (1, 0, 3) and st.rotation_deg == 30 and st.materials[1].alpha == 0.1
    assert st.base_material.alpha == 0.3 and st.epoch == 1 and st.exposure == 1.0 and st.last_seq == 6
    # one effect class per kind (worker/protocol/effects.py): only the edited object's new
    # material rebases the strokes
    assert effects[:5] == [NoEffect(), NoEffect(), NewMaterial("b", False), NewMaterial("a", True), NoEffect()]
    assert isinstance(effects[5], Save) and effects[5].save.name == "x" and st.pending_saves[0].name == "x"
    ro = st.model_copy(update={"readonly": True})
    with pytest.raises(ValueError, match="read-only"):
        apply(ro, client_msg.validate_python({"seq": 7, "type": "stroke", "stroke": STROKE}))


def test_a_fit_is_bounded_in_rows(bunny_renderer):
    """Every view a stroke is painted in adds rows; past max_rows the fit keeps every
    s-th unpainted row (weighted s), so its cost stays bounded and it still matches the full fit."""
    from worker.fit.fitter import Fitter

    r = bunny_renderer
    dull = Lambert(albedo=(0.4, 0.4, 0.4))
    full = Fitter(r, "bunny", base_material=dull, fit_scale=1.0, max_rows=10**9)
    capped = Fitter(r, "bunny", base_material=dull, fit_scale=1.0, max_rows=2000)
    for fx in (full, capped):
        fx.add_view()
        fx.add_stroke({"points": [[62, 62], [88, 64]], "color": [4, 4, 4], "diameter": 10})
    assert full.row_stride() == 1 and capped.row_stride() == -(-full.views[0].n // 2000)
    a, b = full.fit(), capped.fit()
    pa, pb = full.predicted(a.solve.coefficients), capped.predicted(b.solve.coefficients)
    rel = np.sqrt(((pa - pb) ** 2).mean()) / np.sqrt((pa ** 2).mean())
    assert rel < 0.02, f"capped fit differs from the full one by {rel:.4f}"


def test_frame_encoding_and_curves():
    hdr = {"frame": 3, "ack": 7, "width": 2, "height": 1, "format": "jpeg"}
    h, img = decode_frame(encode_frame(hdr, b"\xff\xd8jpeg"))
    assert h == hdr and img == b"\xff\xd8jpeg"
    c = brdf_curve(GGX(alpha=0.2, specular=(0.5, 0.5, 0.5)))
    v = np.asarray(c["values"])
    assert len(c["theta_deg"]) == len(v) and v[0, 0] > v[30, 0] > 0     # falls off from the peak
    # the studio's default grey plastic: no spike where ωi reaches the horizon (θh = 45°), and
    # nothing past it; the plot's largest value is its peak at normal incidence
    for m in (GGX(), GGX(alpha=0.3, specular=(0.04, 0.04, 0.04), albedo=(0.55, 0.38, 0.22))):
        c = brdf_curve(m)
        th, v, s = np.asarray(c["theta_deg"]), np.asarray(c["values"]), np.asarray(c["specular"])
        assert np.isfinite(v).all() and v.max() <= v[0].max() * (1 + 1e-9), (m, v.max(), th[v.max(axis=1).argmax()])
        assert (v[th >= 45] == 0).all() and (s[th >= 45] == 0).all() and (s[th < 45] > 0).all()


def test_stream_schema_is_current():
    """stream-schema.json (client messages, events, frame header) is generated from the models the
    server validates with (glint schema --out stream-schema.json)."""
    import json
    from pathlib import Path

    from worker.protocol import stream_schema

    path = Path(__file__).resolve().parents[2] / "stream-schema.json"
    assert json.loads(path.read_text()) == json.loads(json.dumps(stream_schema())), \
        "stream-schema.json drifted: run `glint schema --out stream-schema.json`"


def test_the_api_process_loads_no_numerical_libraries():
    """The server imports only worker's public modules; Embree, OpenCV and the QP solver
    stay out of the API process."""
    import subprocess
    import sys

    code = ("import sys; from server.main import create_app; create_app(); "
            "import server.routes.sessions, server.routes.assets; "
            "print(','.join(m for m in ('embreex', 'cv2', 'daqp', 'trimesh') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"the API process imported {out.stdout.strip()}"


def test_worker_never_imports_server():
    """Every worker module, the command line's included: the server's commands are in
    server/cli.py and the ``glint`` command is composed in glint/cli.py."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2] / "worker"
    bad = [str(p) for p in root.rglob("*.py") if "from server" in p.read_text() or "import server" in p.read_text()]
    assert not bad, bad


def test_apply_never_changes_the_state_it_is_given(bunny_renderer):
    """``apply`` copies the state shallowly (copy-on-write: a deep copy per message
    was 12% of a worker under load), so no message may edit a nested value in place: for every
    message type the input state dumps the same before and after."""
    import json

    from worker.protocol import StateError, _MESSAGES

    sc = bunny_renderer.scene
    st = new_state(sc.spec)
    st.variants = []
    examples = {
        "view": {"eye": [0.4, 0.6, 3.0], "drag": True}, "light": {"rotation_deg": 30, "intensity": 1.5},
        "material": {"material": {"model": "lambert", "albedo": [0.2, 0.3, 0.4]}},
        "stroke": {"stroke": STROKE}, "undo": {}, "redo": {}, "fit": {"constrained": False, "unpainted_weight": 0.5},
        "save": {"name": "x"}, "display": {"exposure": 1.0, "tone": "aces", "quality": 70, "shadow": True},
        "variant": {"index": 0}, "environment": {"index": 0},
        "move": {"object": "bunny", "transform": {"translate": [0.1, 0, 0]}},
        "renderer": {"kind": "cuts"}, "paint": {"gloss": 80.0, "aspecular": {"15": [0.5, 0.5, 0.5]}},
        "object": {"object": "bunny"}, "pick": {"u": 0.5, "v": 0.5}, "convert": {"model": "ggx"},
        "region": {"action": "paint", "name": "seat"},
    }
    assert set(examples) == set(_MESSAGES), set(_MESSAGES) ^ set(examples)
    applied = 0
    for i, (t, fields) in enumerate(examples.items()):
        before = json.dumps(st.model_dump(mode="json"), sort_keys=True)
        try:
            after, _ = apply(st, client_msg.validate_python({"seq": i, "type": t, **fields}))
        except StateError:
            continue                     # not applicable to this scene (e.g. no variants): nothing changes
        assert json.dumps(st.model_dump(mode="json"), sort_keys=True) == before, f"{t} changed its input state"
        applied += 1
        st = after
    assert applied >= 10, applied


def test_a_frame_that_may_give_way_reports_its_pause_apart(bunny_renderer):
    """A frame answering no stroke stands aside at its checkpoints while strokes are
    handled elsewhere; the pause is the header's ms_paused, not render time (which sets the
    level of detail), and a checkpoint saying the frame is not wanted drops it unchanged."""
    import time

    from worker.renderers.base import FrameCancelled

    rt = _runtime(bunny_renderer)
    rt.handle({"seq": 1, "type": "view", "eye": [0.3, 0.6, 3.1], "drag": True})
    calls = []

    def pause_once() -> bool:
        calls.append(1)
        if len(calls) == 1:
            time.sleep(0.2)         # a stroke elsewhere
        return False

    t0 = time.perf_counter()
    hdr, jpeg = rt.frame(1, cancelled=pause_once)
    wall = (time.perf_counter() - t0) * 1e3
    assert len(calls) >= 1 and jpeg
    assert hdr["ms_paused"] >= 200, hdr
    assert hdr["ms_render"] + hdr["ms_encode"] + hdr["ms_paused"] <= wall + 1.0, (hdr, wall)
    assert hdr["ms_render"] <= wall - 199, (hdr, wall)
    n = rt.frame_no
    with pytest.raises(FrameCancelled):
        rt.frame(2, cancelled=lambda: True)         # the session's own stroke came
    assert rt.frame_no == n


def test_strokes_paint_a_region_in_a_session(bunny_renderer):
    """The region message: strokes then make a region (the rest of the bunny keeps its
    material), undo and redo refit it, a rename and an erase change the material, and a stroke
    after ``stop`` fits one BRDF over the regions material again."""
    from worker.models import Regions

    rt = _runtime(bunny_renderer)
    base = rt.state.materials[0]
    ev = rt.handle({"seq": 1, "type": "region", "action": "paint", "name": "ear"})
    assert ev[0]["type"] == "fit" and ev[0]["stats"]["painting"] == "ear" and rt.state.region == "ear"
    rt.handle({"seq": 2, "type": "stroke", "stroke": {**STROKE, "mode": "scale", "scale": 0.3}})
    fit = rt.fit_if_needed()[0]
    m = rt.state.materials[0]
    assert isinstance(m, Regions) and fit["material"]["model"] == "regions" and m.base == base
    assert fit["stats"]["regions"] == ["ear"] and fit["stats"]["achieved"] > 0.8 and fit["stats"]["spill_far"] < 0.03
    assert rt._override() is None                # the renderer blends the layers itself
    rt.handle({"seq": 3, "type": "undo"})
    assert rt.fit_if_needed()[0]["material"] == base.model_dump(mode="json")
    rt.handle({"seq": 4, "type": "redo"})
    assert rt.fit_if_needed()[0]["material"]["model"] == "regions"
    ev = rt.handle({"seq": 5, "type": "region", "action": "rename", "name": "ear", "new_name": "left ear"})
    assert ev[0]["stats"]["regions"] == ["left ear"] and rt.state.region == "left ear"
    assert rt.state.base_material == rt.state.materials[0]      # the strokes so far are part of it
    with pytest.raises(Exception, match="no region 'ear'"):
        rt.handle({"seq": 6, "type": "region", "action": "erase", "name": "ear"})
    rt.handle({"seq": 7, "type": "region", "action": "stop"})
    rt.handle({"seq": 8, "type": "stroke", "stroke": STROKE})
    assert rt.fit_if_needed()[0]["material"]["model"] == "srbf"
    rt.handle({"seq": 9, "type": "material", "material": rt.state.base_material.model_dump(mode="json")})
    ev = rt.handle({"seq": 10, "type": "region", "action": "erase", "name": "left ear"})
    assert ev[0]["material"] == base.model_dump(mode="json") and rt.state.region is None
def test_region_steps_merge_take_a_material_and_are_undone(bunny_renderer):
    """A region can take a material (from the library: any material) and be merged into
    another; undo, once the strokes since are undone, takes these steps back one by one and
    redo brings them again, each a new epoch as the region message was; the server's state
    follows the worker's from the events alone."""
    from worker.models import Regions
    from worker.protocol.events import apply_event, worker_event

    rt = _runtime(bunny_renderer)
    mirror = rt.state.model_copy(deep=True)            # the server's copy, events applied

    def send(seq, msg):
        nonlocal mirror
        raw = {"seq": seq, **msg}
        mirror = apply(mirror, client_msg.validate_python(raw))[0]
        evs = rt.handle(raw) + rt.fit_if_needed()
        for ev in evs:
            if ev.get("type") == "fit":
                mirror = apply_event(mirror, worker_event(ev))[0]
        return evs

    send(1, {"type": "region", "action": "paint", "name": "ear"})
    send(2, {"type": "stroke", "stroke": {**STROKE, "mode": "scale", "scale": 0.3}})
    send(3, {"type": "region", "action": "paint", "name": "belly"})
    send(4, {"type": "stroke", "stroke": {**STROKE, "points": [[60, 80], [90, 82]], "mode": "scale", "scale": 2.0}})
    two = rt.state.materials[0]
    assert isinstance(two, Regions) and [r.name for r in two.regions] == ["ear", "belly"]
    red = {"model": "ggx", "alpha": 0.3, "specular": [0.2, 0.2, 0.2], "albedo": [0.6, 0.05, 0.05]}
    ev = send(5, {"type": "region", "action": "material", "name": "ear", "material": red})
    assert ev[0]["material"]["regions"][0]["material"]["model"] == "ggx"
    ev = send(6, {"type": "region", "action": "merge", "name": "ear", "new_name": "belly"})
    merged = rt.state.materials[0]
    assert [r.name for r in merged.regions] == ["belly"] and ev[0]["stats"]["regions"] == ["belly"]
    assert len(merged.regions[0].vertices) >= max(len(r.vertices) for r in two.regions)
    with pytest.raises(Exception, match="no region 'nose'"):
        rt.handle({"seq": 7, "type": "region", "action": "merge", "name": "belly", "new_name": "nose"})
    # undo: the merge, then the material; redo: the material again
    ev = send(8, {"type": "undo"})
    assert ev[0]["rebase"] and [r.name for r in rt.state.materials[0].regions] == ["ear", "belly"]
    assert rt.state.materials[0].regions[0].material.model == "ggx"
    ev = send(9, {"type": "undo"})
    assert rt.state.materials[0] == two
    ev = send(10, {"type": "redo"})
    assert rt.state.materials[0].regions[0].material.model == "ggx"
    for k in ("materials", "base_material", "region", "epoch"):
        assert getattr(mirror, k) == getattr(rt.state, k), k
    # a stroke after an undo: the steps undone are gone
    send(11, {"type": "undo"})
    send(12, {"type": "region", "action": "paint", "name": "belly"})
    send(13, {"type": "stroke", "stroke": {**STROKE, "points": [[60, 80], [90, 82]], "mode": "scale", "scale": 1.5}})
    send(14, {"type": "undo"})
    ev = send(15, {"type": "redo"})
    assert rt.state.materials[0].regions[-1].name == "belly"
    assert rt.handle({"seq": 16, "type": "redo"})[0]["type"] == "note"         # nothing more to redo
    # a material given otherwise (the Material panel) is not undone by a region step's undo
    send(17, {"type": "region", "action": "erase", "name": "ear"})
    send(18, {"type": "material", "material": {"model": "lambert", "albedo": [0.2, 0.4, 0.6]}})
    assert rt.handle({"seq": 19, "type": "undo"})[0]["type"] == "note"
    assert rt.state.materials[0].model == "lambert"


def test_a_highlight_the_light_cannot_give_gets_guidance_after_its_frame(bunny_renderer):
    """A bright white stroke on the bunny under the sunset falls short with one BRDF: after its
    frame (off the path from stroke to frame) the session sends a guidance event with what the
    light near the mirror directions covers (close to what the fit reached), the environment
    rotation that covers most, and a painted region on offer. Painted again under that rotation
    the same stroke reaches more. A darkening (one BRDF: its specular part only adds light) gets
    no light figures, only the region on offer; in region mode it reaches the change."""
    def stroke(rt, seq, **kw):
        rt.handle({"seq": seq, "type": "stroke", "stroke": {**STROKE, **kw}})
        fit = rt.fit_if_needed()[0]
        rt.frame(seq)
        return fit, [e for e in rt.after_frame() if e["type"] == "guidance"]

    rt = _runtime(bunny_renderer)
    rt.frame(-1)
    fit, got = stroke(rt, 1)
    assert fit["stats"]["achieved"] < 0.8 and len(got) == 1, (fit["stats"], got)
    g = got[0]
    assert g["object"] == "bunny" and g["region"] and "painting the stroke as a region" in g["message"]
    assert 0 <= g["covered"] <= g["covered_at_rotation"] <= 1 and 0 <= g["rotate_to_deg"] < 360
    assert abs(g["covered"] - fit["stats"]["achieved"]) < 0.1, (g, fit["stats"]["achieved"])
    server_event.validate_python(g)
    rt2 = _runtime(bunny_renderer)
    rt2.frame(-1)
    rt2.handle({"seq": 1, "type": "light", "rotation_deg": g["rotate_to_deg"]})
    rt2.frame(1)
    fit2, _ = stroke(rt2, 2)
    assert fit2["stats"]["achieved"] > fit["stats"]["achieved"], (fit2["stats"]["achieved"], fit["stats"]["achieved"])
    rt3 = _runtime(bunny_renderer)
    rt3.frame(-1)
    fit3, got3 = stroke(rt3, 1, mode="scale", scale=0.3)
    assert fit3["stats"]["achieved"] < 0.8 and len(got3) == 1, (fit3["stats"], got3)
    assert got3[0]["region"] and got3[0]["covered"] is None and got3[0]["mirror"] is None, got3
    assert "painting the stroke as a region" in got3[0]["message"]
    server_event.validate_python(got3[0])
    rt4 = _runtime(bunny_renderer)
    rt4.frame(-1)
    rt4.handle({"seq": 1, "type": "region", "action": "paint", "name": "belly"})
    rt4.fit_if_needed()
    fit4, got4 = stroke(rt4, 2, mode="scale", scale=0.3)
    assert fit4["stats"]["achieved"] >= 0.8 and got4 == [], (fit4["stats"], got4)


def test_a_view_that_keeps_changing_builds_nothing_for_strokes(bunny_renderer):
    """What a stroke in the current view needs (its fit view) is built once the view has stayed
    VIEW_SETTLE_S: an orbit without the drag flag (a new camera every frame) starts no build,
    each of which took a core from its frames; the view it stops at gets its build."""
    import time

    from worker.jobs.fit_driver import VIEW_SETTLE_S

    rt = _runtime(bunny_renderer)
    rt.handle({"seq": 1, "type": "stroke", "stroke": STROKE})
    rt.fit_if_needed()
    _complete_views(rt)

    def view_builds():
        return [k for k in rt._pending if k[0] == "view"]
    for k in range(3):
        rt.handle({"seq": 2 + k, "type": "view", "eye": [0.2 * k, 0.6, 3.1]})
        wait = rt.prefetch()
        assert 0 < wait <= VIEW_SETTLE_S and not view_builds(), (wait, view_builds())
    time.sleep(wait)
    assert rt.prefetch() == 0.0
    assert len(view_builds()) == 1 and view_builds()[0][3][0] == rt.state.camera.model_dump_json()
    rt._pending[view_builds()[0]].result(timeout=120)


def test_the_background_builder_runs_below_the_sessions():
    """What the builder prepares (fit views, the per-vertex transfer) gives way to strokes and
    frames: its thread runs BUILDER_NICE levels below the process (Linux thread niceness)."""
    import os
    import threading

    from worker.jobs import fit_driver

    here = os.getpriority(os.PRIO_PROCESS, 0)
    there = fit_driver._builder.submit(lambda: os.getpriority(os.PRIO_PROCESS, threading.get_native_id())).result()
    assert there == min(19, here + fit_driver.BUILDER_NICE), (here, there)


def test_settled_frames_are_refined_and_moving_ones_interpolated(bunny_renderer):
    """The default mode where it is looked at: a session's settled (anti-aliased) frame is
    shaded per pixel where vertex interpolation is wrong (refined), its one-sample frames while
    the camera moves are interpolated alone (an orbit refined ran at half the rate)."""
    r = bunny_renderer
    st = new_state(r.scene.spec, materials=[GGX(alpha=0.1, albedo=(0.1, 0.1, 0.1), specular=(0.8, 0.8, 0.8)).model_dump()])
    rt = SessionRuntime(r.scene, CutRenderer(r.scene, r.data), {"state": st.model_dump(mode="json"), "strokes": []})
    seen = []
    real = rt.renderer.render
    rt.renderer.render = lambda req: seen.append((req.samples, req.shading)) or real(req)
    rt.frame(-1)                                     # the first frame: one sample (no hits traced yet)
    rt.handle({"seq": 1, "type": "view", "eye": [0.4, 0.7, 3.0]})
    rt.frame(1)                                      # the camera moved: one sample
    assert rt.needs_still_frame()
    hdr, _ = rt.frame(1)                             # the settled frame
    assert hdr["samples"] > 1
    assert [sh for s, sh in seen if s == 1] and all(sh == "vertex" for s, sh in seen if s == 1), seen
    assert seen[-1] == (hdr["samples"], "refined"), seen


def test_a_save_sends_the_settled_frame_again_without_drawing(bunny_renderer):
    """A message that changes nothing the image depends on (a save) is answered with the settled
    frame it shows, under its own ack: drawn anew it was a one-sample frame (faceted where the
    still is refined) followed by the still again, 7 s for a sharp paint on the test bunny."""
    r = bunny_renderer
    st = new_state(r.scene.spec, materials=[GGX(alpha=0.1, albedo=(0.1, 0.1, 0.1), specular=(0.8, 0.8, 0.8)).model_dump()])
    rt = SessionRuntime(r.scene, CutRenderer(r.scene, r.data), {"state": st.model_dump(mode="json"), "strokes": []})
    seen = []
    real = rt.renderer.render
    rt.renderer.render = lambda req: seen.append(req.samples) or real(req)
    rt.frame(-1)
    while rt.needs_still_frame():
        rt.frame(-1)
    hdr, jpeg = rt.frame(-1)                          # the settled frame, asked for again: not drawn again
    assert hdr["settled"]
    drawn = len(seen)
    ev = rt.handle({"seq": 1, "type": "save", "name": "kept"})
    assert [e for e in ev if e["type"] == "save"], ev
    again, same = rt.frame(1)
    assert len(seen) == drawn and same == jpeg, seen           # no render, the same picture
    assert again["ack"] == 1 and again["settled"] and again["frame"] == hdr["frame"] + 1 and again["ms_render"] == 0
    assert not rt.needs_still_frame()
    # anything the image depends on draws again: the exposure, then the material
    rt.handle({"seq": 2, "type": "display", "exposure": 0.5})
    rt.frame(2)
    assert len(seen) == drawn + 1, seen
    rt.handle({"seq": 3, "type": "material", "material": Lambert(albedo=(0.3, 0.5, 0.2)).model_dump()})
    rt.frame(3)
    assert len(seen) == drawn + 2, seen


def _settle_background(rt, ack: int, timeout: float = 240.0) -> list[dict]:
    """Frames and background work until the session has nothing more to take (completed fit
    views, a region fit in parts): the fit and note events it emitted meanwhile, in order."""
    fits = []
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        rt.frame(ack)
        rt.after_frame()
        futs = [f for _, _, f in rt._completions.values()]
        if rt._parts_future is not None:
            futs.append(rt._parts_future[2])
        for f in futs:
            f.result(timeout=max(1.0, end - time.monotonic()))
        if not rt.absorb() and not futs:
            rt.prefetch()
            if not rt._completions and rt._parts_future is None and rt._parts_pending is None:
                return fits
        fits += [e for e in rt.fit_if_needed() + rt.take_events() if e.get("type") in ("fit", "note")]
    raise AssertionError(f"the session's background work did not settle in {timeout} s")


def test_a_region_stroke_short_of_its_change_is_refitted_in_parts(bunny_renderer):
    """A white highlight across the bunny painted as a region: on the stroke's path the region is
    fitted in one part, which falls short of the change; after the frame the same strokes are
    fitted in parts in the background (the fit's stats say one will follow), and the session
    takes that fit (a fit event marked ``refined_in_parts``, the material with the parts) as it
    reaches more of the change. Undo refits the strokes left, and a stale result is dropped."""
    from worker.models import Regions

    rt = _runtime(bunny_renderer)
    rt.frame(0)
    rt.handle({"seq": 1, "type": "region", "action": "paint", "name": "hl"})
    rt.handle({"seq": 2, "type": "stroke", "stroke": STROKE})
    first = rt.fit_if_needed()[0]["stats"]
    assert first["parts"] == 1 and first["achieved"] < 0.8 and first["parts_later"], first
    fits = [e for e in _settle_background(rt, 2) if e["type"] == "fit"]
    one = [f["stats"] for f in fits if not f["stats"].get("refined_in_parts")]
    parts = [f["stats"] for f in fits if f["stats"].get("refined_in_parts")]
    last_one = (one or [first])[-1]
    print(f"region highlight in the session: one part {last_one['achieved']:.3f}, "
          f"in parts {[(p['parts'], round(p['achieved'], 3)) for p in parts]}")
    assert len(parts) == 1, fits
    p = parts[0]
    assert p["parts"] >= 2 and p["achieved"] >= last_one["achieved"] + 0.02, (last_one, p)
    assert p["regions"] == ["hl"]                # one region in the studio's list, in parts
    m = rt.state.materials[0]
    assert isinstance(m, Regions) and [g.name for g in m.regions] == [f"hl/{i + 1}" for i in range(p["parts"])]
    # a stroke after it: fitted in one part again, and a parts fit started for the old strokes
    # is dropped when it arrives after a newer fit
    rt.handle({"seq": 3, "type": "stroke", "stroke": {**STROKE, "points": [[60, 76], [86, 78]]}})
    assert rt.fit_if_needed()[0]["stats"]["parts"] == 1
    rt.frame(3)
    rt.after_frame()
    key = rt._parts_key()
    rt._fit_serial += 1                          # as a newer fit would
    if rt._parts_future is not None:
        rt._parts_future[2].result(timeout=240)
    assert not rt._absorb_parts() and rt._parts_key() != key
    rt.handle({"seq": 4, "type": "undo"})
    rt.handle({"seq": 5, "type": "undo"})
    assert rt.fit_if_needed()[0]["material"]["model"] != "regions"


def test_a_closed_session_drops_its_refit_in_parts(bunny_renderer):
    """A region refit in parts still queued on the builder when the session closes is cancelled:
    it never runs on the renderer the next session draws with, and nothing is taken from it."""
    import threading

    from worker.jobs import fit_driver

    rt = _runtime(bunny_renderer)
    rt.frame(0)
    rt.handle({"seq": 1, "type": "region", "action": "paint", "name": "hl"})
    rt.handle({"seq": 2, "type": "stroke", "stroke": STROKE})
    assert rt.fit_if_needed()[0]["stats"]["parts_later"]
    gate, busy = threading.Event(), None
    end = time.monotonic() + 240
    while rt._parts_future is None and time.monotonic() < end:
        rt.frame(2)
        if rt._parts_pending is not None and not rt.fit_pending():
            busy = fit_driver._builder.submit(gate.wait)      # the builder busy: the refit queues
            rt.after_frame()
            break
        rt.after_frame()
        for _, _, f in list(rt._completions.values()):
            f.result(timeout=240)
        rt.absorb()
        rt.fit_if_needed()
    try:
        assert busy is not None and rt._parts_future is not None, "the refit in parts was not queued"
        fut = rt._parts_future[2]
        rt.close()
        assert fut.cancelled() and rt._parts_future is None and rt._parts_pending is None
    finally:
        gate.set()
        if busy is not None:
            busy.result(timeout=60)
    assert not rt._absorb_parts()


def test_a_fit_in_parts_that_gains_nothing_is_said(bunny_renderer, monkeypatch):
    """The studio was told a fit in parts would follow (``parts_later``): when it reaches no more
    of the change (here: a gain it cannot make), a note says so and the one-part fit stays."""
    from worker.jobs import fit_driver

    monkeypatch.setattr(fit_driver, "PARTS_GAIN", 10.0)
    rt = _runtime(bunny_renderer)
    rt.frame(0)
    rt.handle({"seq": 1, "type": "region", "action": "paint", "name": "hl"})
    rt.handle({"seq": 2, "type": "stroke", "stroke": STROKE})
    assert rt.fit_if_needed()[0]["stats"]["parts_later"]
    evs = _settle_background(rt, 2)
    assert not any(e.get("stats", {}).get("refined_in_parts") for e in evs), evs
    notes = [e["message"] for e in evs if e["type"] == "note"]
    assert len(notes) == 1 and notes[0].endswith("the region stays in one part"), notes
    assert [g.name for g in rt.state.materials[0].regions] == ["hl"]
