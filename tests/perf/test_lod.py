"""The session picks each frame's level of detail from the measured cost of recent full frames
against its frame budget (issue 16), anti-aliases still frames, and toggles the ground shadow
from a ``display`` message; the frame header reports what it used."""
from pathlib import Path

import pytest

from helpers import open_renderer

from worker.jobs import session as S
from worker.jobs.session import SessionRuntime
from worker.jobs.state import new_state
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
    first, _ = rt.frame(0)
    assert first["lod"] is False and first["samples"] == S.STILL_SAMPLES   # a still frame: anti-aliased
    hdrs = [_orbit(rt, i) for i in range(1, 6)]
    assert all(h["lod"] is False and h["samples"] == 1 for h in hdrs)
    assert hdrs[-1]["width"] == rt.state.camera.width
    still = _orbit(rt, 6, drag=False, dx=0.0)             # the user lets go
    assert still["lod"] is False and still["samples"] == S.STILL_SAMPLES


def test_drag_level_of_detail_when_full_frames_do_not_fit(bunny_renderer, monkeypatch):
    rt = _runtime(bunny_renderer)
    rt.frame_budget_ms = 1e-3                           # nothing fits
    rt.frame(0)
    h1 = _orbit(rt, 1)                                  # no full frame with a moving view measured yet
    assert h1["lod"] is False
    hdrs = [_orbit(rt, i) for i in range(2, 6)]
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
    # the drag ends: a still frame, anti-aliased
    h = _orbit(rt, 10, drag=False)
    assert h["lod"] is False and h["samples"] == S.STILL_SAMPLES and not rt.needs_still_frame()
    # a camera moving without drag flags: full quality, one sample per frame; once it stops, the
    # still frame the runner asks for when idle is anti-aliased
    h = _orbit(rt, 11, drag=False)
    assert h["lod"] is False and h["samples"] == 1 and rt.needs_still_frame()
    h, _ = rt.frame(11)
    assert h["samples"] == S.STILL_SAMPLES and not rt.needs_still_frame()


def test_display_message_toggles_the_ground_shadow(cache_dir):
    from worker.scene import load_scene

    r = open_renderer(load_scene(ROOT / "tests" / "scenes" / "bunny-ground.json"))
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
