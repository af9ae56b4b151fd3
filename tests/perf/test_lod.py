"""The session picks each frame's level of detail from the measured cost of recent full frames
against its frame budget, anti-aliases still frames, and toggles the ground shadow
from a ``display`` message; the frame header reports what it used."""
from pathlib import Path

import pytest

from helpers import open_renderer, scene_file

from worker.jobs import lod as S
from worker.jobs.runtime import SessionRuntime
from worker.protocol import new_state
from worker.renderers.cuts import CutRenderer

ROOT = Path(__file__).resolve().parents[2]


def _runtime(r):
    st = new_state(r.scene.spec)
    return SessionRuntime(r.scene, CutRenderer(r.scene, r.data), {"state": st.model_dump(mode="json"), "strokes": []})


def _orbit(rt, seq, drag=True, dx=0.05):
    eye = list(rt.state.camera.eye)
    eye[0] += dx
    rt.handle({"seq": seq, "type": "view", "eye": eye, "drag": drag})
    hdr, jpeg = rt.frame(seq)
    assert jpeg[:2] == b"\xff\xd8"
    return hdr


def test_full_frames_while_dragging_when_they_fit_the_budget(bunny_renderer):
    rt = _runtime(bunny_renderer)
    rt.frame_budget_ms = 1e6                            # everything fits
    first, _ = rt.frame(0)               # the opening frame: one sample at once, then anti-aliased
    assert first["lod"] is False and first["samples"] == 1 and rt.needs_still_frame()
    first, _ = rt.frame(0)
    assert first["samples"] == S.STILL_SAMPLES
    hdrs = [_orbit(rt, i) for i in range(1, 6)]
    assert all(h["lod"] is False and h["samples"] == 1 for h in hdrs)
    assert hdrs[-1]["width"] == rt.state.camera.width
    # the user lets go: at once one sample (the anti-aliased hits of this camera are not traced
    # yet), then the still frame the runner asks for when idle, anti-aliased
    h = _orbit(rt, 6, drag=False, dx=0.0)
    assert h["lod"] is False and h["samples"] == 1 and rt.needs_still_frame()
    still, _ = rt.frame(6)
    assert still["lod"] is False and still["samples"] == S.STILL_SAMPLES and not rt.needs_still_frame()
    # a material change in that settled view: one sample at once (a new material's settled,
    # refined frame may cost seconds: a sharp paint), then the still, anti-aliased
    rt.handle({"seq": 7, "type": "material", "material": {"model": "lambert", "albedo": [0.6, 0.3, 0.2]}})
    h, _ = rt.frame(7)
    assert h["samples"] == 1 and rt.needs_still_frame() and not h["settled"]
    h, _ = rt.frame(7)
    # the still says it is the last frame of this state (the studio's tests wait for it)
    assert h["samples"] == S.STILL_SAMPLES and not rt.needs_still_frame() and h["settled"]


def test_drag_level_of_detail_when_full_frames_do_not_fit(bunny_renderer, monkeypatch):
    rt = _runtime(bunny_renderer)
    rt.frame_budget_ms = 1e-3                           # nothing fits
    rt.lod.full_ms["view"].clear()
    h1 = _orbit(rt, 1)                                  # no full frame with a moving view measured yet
    assert h1["lod"] is False and not h1["quick"]
    for i in (2, 3):                                    # nor quick ones (full resolution, coarse cuts):
        h = _orbit(rt, i)                               # two, the first may have built the coarse cuts
        assert h["lod"] is False and h["quick"] and h["width"] == rt.state.camera.width, h
    hdrs = [_orbit(rt, i) for i in range(4, 6)]
    assert all(h["lod"] is True and h["samples"] == 1 for h in hdrs)
    monkeypatch.setattr(S, "REPROBE_S", 0.0)              # time for another try at full quality
    assert _orbit(rt, 6)["lod"] is False
    monkeypatch.setattr(S, "REPROBE_S", 1e9)
    assert _orbit(rt, 7)["lod"] is True
    rt.frame_budget_ms = 1e6                            # the machine got quieter: the probe decides
    monkeypatch.setattr(S, "REPROBE_S", 0.0)
    _orbit(rt, 8)
    monkeypatch.setattr(S, "REPROBE_S", 1e9)
    assert _orbit(rt, 9)["lod"] is False
    # the drag ends: one sample at once, then the still frame, anti-aliased
    h = _orbit(rt, 10, drag=False)
    assert h["lod"] is False and h["samples"] == 1 and rt.needs_still_frame()
    h, _ = rt.frame(10)
    assert h["lod"] is False and h["samples"] == S.STILL_SAMPLES and not rt.needs_still_frame()
    # a camera moving without drag flags: full quality, one sample per frame; once it stops, the
    # still frame the runner asks for when idle is anti-aliased
    h = _orbit(rt, 11, drag=False)
    assert h["lod"] is False and h["samples"] == 1 and rt.needs_still_frame()
    h, _ = rt.frame(11)
    assert h["samples"] == S.STILL_SAMPLES and not rt.needs_still_frame()


def test_display_message_toggles_the_ground_shadow(cache_dir):
    from worker.scene import load_scene

    r = open_renderer(load_scene(scene_file("bunny-ground.json")))
    rt = _runtime(r)
    hdr, _ = rt.frame(0)
    assert hdr["shadow"] is True                        # the scene's default
    rt.handle({"seq": 1, "type": "display", "shadow": False})
    assert rt.frame(1)[0]["shadow"] is False
    rt.handle({"seq": 2, "type": "display", "shadow": True})
    assert rt.frame(2)[0]["shadow"] is True


def test_scenes_without_ground_report_no_shadow(bunny_renderer):
    rt = _runtime(bunny_renderer)
    rt.handle({"seq": 1, "type": "display", "shadow": True})
    assert rt.frame(1)[0]["shadow"] is None


def _fine_srbf():
    """An srbf on the default (multi-scale) basis with weight on its finest level: the kind of
    material a stroke fit produces (it asks the renderer for 0.03 rad clusters)."""
    import numpy as np

    from worker.fit.basis import default_basis
    from worker.models import SRBF

    b = default_basis()
    lam = np.asarray(b.bandwidths, np.float64)
    c = np.where((lam == lam.max())[:, None], 0.05, 0.002) * np.ones((b.J, 3))
    return SRBF.model_validate(b.to_material(c, np.array([0.3, 0.25, 0.2])))


def test_materials_are_packed_once_by_content(bunny_renderer, monkeypatch):
    """A session's state is copied by every message, so each frame brings new material objects
    with the same content: they are packed once (an srbf's table costs more than a frame)."""
    from worker.models import SRBF
    from worker.renderers import FrameRequest

    m = _fine_srbf()
    r = CutRenderer(bunny_renderer.scene, bunny_renderer.data)
    calls = []
    orig = SRBF.pack
    monkeypatch.setattr(SRBF, "pack", lambda self: calls.append(1) or orig(self))
    cam = r.scene.spec.camera
    for k in range(3):
        r.render(FrameRequest(camera=cam, materials=[m.model_copy(deep=True)]))
    assert len(calls) == 1, f"packed {len(calls)} times for 3 frames of one material"
    changed = m.model_copy(update={"albedo": (0.1, 0.1, 0.1)})
    r.render(FrameRequest(camera=cam, materials=[changed]))
    assert len(calls) == 2, "a changed material must be packed again"


def test_drag_frames_refine_no_finer_than_the_drag_limit(bunny_renderer):
    """At the drag level of detail a fine srbf is shaded with clusters no finer than DRAG_REFINE:
    cheaper (the demo chair's orbit: 32 → 25 ms per frame on one core), and close to the drag frame
    refined to the material's own radius (measured 2026-11-23: 0.03% relative RMSE; bound 1%)."""
    import numpy as np

    from worker.renderers import FrameRequest
    from worker.renderers.cuts import renderer as R

    m = _fine_srbf()
    assert m.pack().refine_radius < R.DRAG_REFINE
    r = CutRenderer(bunny_renderer.scene, bunny_renderer.data)
    cam = r.scene.spec.camera.model_copy(update={"width": 320, "height": 240})
    clamped = r.render(FrameRequest(camera=cam, materials=[m], lod="drag"))
    own = CutRenderer(bunny_renderer.scene, bunny_renderer.data)
    own._drag_materials = lambda mats: mats               # the material's own refinement
    exact = own.render(FrameRequest(camera=cam, materials=[m], lod="drag"))
    obj = exact.object_id >= 0
    a, b = clamped.radiance[obj], exact.radiance[obj]
    rel = float(np.sqrt(((a - b) ** 2).mean() / (b ** 2).mean()))
    assert 0 < rel < 0.01, f"drag refinement changed the object by {rel:.4f} relative RMSE"


def test_under_load_drag_frames_drop_to_a_quarter_of_the_resolution(cache_dir, monkeypatch):
    """A session's frame budget is its share of the worker (sessions that moved
    something in the last second); when even half-resolution drag frames do not fit it, they
    are drawn at a quarter, and half is tried again after REPROBE_S."""
    from worker.scene import load_scene

    r = open_renderer(load_scene(scene_file("bunny.json")))
    cam = r.scene.spec.camera.model_copy(update={"width": 640, "height": 480})
    st = new_state(r.scene.spec, camera=cam.model_dump(mode="json"))
    rt = SessionRuntime(r.scene, CutRenderer(r.scene, r.data), {"state": st.model_dump(mode="json"), "strokes": []})
    monkeypatch.setattr(S, "REPROBE_S", 1e9)
    monkeypatch.setattr(S, "_active", {})               # no other test's sessions in the count
    rt.frame_budget_ms = 1e6
    _orbit(rt, 1)
    assert S.busy_sessions(__import__("time").monotonic()) == 1     # this session, counted once
    rt.frame_budget_ms = 1e-3                           # full frames never fit: quick ones are measured,
    for i in (2, 3):
        h = _orbit(rt, i)
        assert h["quick"] and (h["width"], h["height"]) == (640, 480), h
    h = _orbit(rt, 4)                                   # they do not fit either: drag level, half first
    assert h["lod"] is True and (h["width"], h["height"]) == (320, 240), h
    h = _orbit(rt, 5)                                   # half did not fit either: a quarter
    assert h["lod"] is True and (h["width"], h["height"]) == (160, 120), h
    rt.lod.last_half = -float("inf")                       # long since the last half frame: try it again
    assert _orbit(rt, 6)["width"] == 320
    # the budget is shared: two busy sessions halve it
    other = SessionRuntime(r.scene, CutRenderer(r.scene, r.data), {"state": st.model_dump(mode="json"), "strokes": []})
    other.handle({"seq": 1, "type": "view", "eye": [0.2, 0.6, 3.2], "drag": True})
    assert S.busy_sessions(__import__("time").monotonic()) == 2


def test_a_still_frame_is_given_up_when_a_message_arrives(bunny_renderer):
    """The anti-aliased still is optional: shaded in parts, abandoned as soon as the session
    has a new message (its frame comes first); drawn in full, it equals the frame in one go."""
    import numpy as np

    from worker.renderers.base import FrameCancelled, FrameRequest, Lighting

    rt = _runtime(bunny_renderer)
    rt.frame(0)
    h = _orbit(rt, 1, drag=False)
    assert h["samples"] == 1 and rt.needs_still_frame()
    with pytest.raises(FrameCancelled):
        rt.frame(1, cancelled=lambda: True)
    assert rt.needs_still_frame()                    # nothing changed: the still is still owed
    h, _ = rt.frame(1, cancelled=lambda: False)
    assert h["samples"] == S.STILL_SAMPLES and not rt.needs_still_frame()
    st = rt.state
    req = dict(camera=st.camera, lighting=Lighting(st.rotation_deg, st.intensity), materials=st.materials, samples=4)
    whole = rt.renderer.render(FrameRequest(**req)).radiance
    parts = rt.renderer.render(FrameRequest(**req, cancelled=lambda: False)).radiance
    np.testing.assert_array_equal(parts, whole)


def test_quick_frames_while_dragging_when_full_ones_do_not_fit_but_theirs_do(bunny_renderer):
    """Between full quality and the half-resolution drag level: full-resolution frames on the
    drag level's cuts, when their measured cost fits the budget and a full frame's does not."""
    rt = _runtime(bunny_renderer)
    rt.frame_budget_ms = 1e6
    _orbit(rt, 1)
    rt.lod.full_ms["view"].extend([1e5, 1e5, 1e5])     # full frames: far over any budget
    rt.frame_budget_ms = 1e4
    hdrs = [_orbit(rt, i) for i in range(2, 6)]
    assert all(h["quick"] and h["lod"] is False and h["width"] == rt.state.camera.width for h in hdrs), hdrs
    assert not any(h["settled"] for h in hdrs)          # a dragging session's frames never are
    assert len(rt.lod.quick_ms["view"]) == 3 and rt.lod.full_ms["view"][-1] == 1e5
    h = _orbit(rt, 6, drag=False, dx=0.0)               # let go: the settled frame follows
    assert rt.needs_still_frame()
    still, _ = rt.frame(6)
    assert still["samples"] == S.STILL_SAMPLES and not still["quick"]
