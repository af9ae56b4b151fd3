"""The edited object of a session changes (``object`` messages), with each object's strokes and
undo history its own; ``pick`` names the object under a point of the last frame; ``convert``
gives a material another model with the same look in the session's view; frames follow the
size the client asks for, within the session's pixel cap. Worker side, no server (the server's
half, the stroke rows of an object's epoch, is in tests/web/test_studio_objects.py)."""
import time

import numpy as np
import pytest
from helpers import open_renderer, scene_file

from worker.jobs.runtime import SessionRuntime
from worker.protocol import StateError, apply, client_msg, new_state
from worker.renderers import FrameRequest, Lighting
from worker.scene import load_scene

# across the right bunny of two-bunnies.json (160×120: it covers u ≈ 0.6-0.77)
STROKE = {"points": [[100, 62], [118, 64]], "color": [4.0, 4.0, 4.0], "diameter": 10, "kappa": 0.05}


@pytest.fixture(scope="module")
def two(shared_assets, cache_dir):
    return open_renderer(load_scene(scene_file("two-bunnies.json")))


def _runtime(r, **state):
    return SessionRuntime(r.scene, r, {"state": new_state(r.scene.spec, **state).model_dump(mode="json"), "strokes": []})


def _means(rt):
    st = rt.state
    out = rt.renderer.render(FrameRequest(camera=st.camera, lighting=Lighting(st.rotation_deg, st.intensity),
                                          materials=st.materials))
    return [out.radiance[out.object_id == k].mean() for k in range(2)]


def _records(rt):
    """The stroke rows of the edited object's epoch as the server keeps them (seq, body, undone)."""
    fx = rt.fitter
    out = []
    for s in fx.history.strokes:
        v = fx.views[s.view]
        out.append({"seq": len(out) + 1, "stroke": STROKE, "camera": v.camera.model_dump(mode="json"),
                    "rotation_deg": v.rotation_deg, "intensity": v.intensity, "undone": False})
    return out


def test_pick_then_paint_the_second_object_only(two):
    rt = _runtime(two)
    assert rt.state.object == "left"
    rt.frame(-1)
    ev = rt.handle({"seq": 1, "type": "pick", "u": 0.68, "v": 0.55})
    assert ev == [{"type": "picked", "seq": 1, "u": 0.68, "v": 0.55, "object": "right"}]
    assert rt.handle({"seq": 2, "type": "pick", "u": 0.02, "v": 0.02})[0]["object"] is None     # background
    before = _means(rt)
    ev = rt.handle({"seq": 3, "type": "object", "object": "right", "strokes": []})
    assert ev[-1]["type"] == "object" and ev[-1]["object"] == "right" and ev[-1]["strokes"] == 0
    assert rt.handle({"seq": 4, "type": "stroke", "stroke": STROKE})[0]["rejected"] is False
    fit = rt.fit_if_needed()
    assert fit[0]["object"] == "right"
    after = _means(rt)
    assert after[1] > 1.1 * before[1], (before, after)             # the painted object brightened
    assert abs(after[0] - before[0]) < 1e-6 * max(1.0, before[0]), (before, after)      # the other did not
    assert rt.state.materials[0] == new_state(two.scene.spec).materials[0]


def test_each_object_keeps_its_strokes_and_undo(two):
    rt = _runtime(two)
    rt.handle({"seq": 1, "type": "object", "object": "right", "strokes": []})
    e_right = rt.state.epoch
    rt.handle({"seq": 2, "type": "stroke", "stroke": STROKE})
    rt.fit_if_needed()
    painted = rt.state.material_of("right")
    recs = _records(rt)
    # to the left object: a fresh epoch, its own base; the right one keeps its fitted material
    rt.handle({"seq": 3, "type": "object", "object": "left", "strokes": []})
    assert rt.state.epoch != e_right and rt.fitter is None
    assert rt.state.material_of("right") is painted
    assert rt.state.edits["right"].epoch == e_right
    # back to the right one: its epoch and its strokes (replayed from its rows), undo works
    ev = rt.handle({"seq": 4, "type": "object", "object": "right", "strokes": recs})
    assert rt.state.epoch == e_right and ev[-1]["strokes"] == 1
    assert rt.fit_if_needed()[0]["stats"]["strokes"] == 1
    assert rt.handle({"seq": 5, "type": "undo"}) == []
    assert rt.fit_if_needed()[0]["stats"]["strokes"] == 0
    assert rt.state.material_of("right") == rt.state.edits["right"].base_material


def test_epochs_stay_distinct_across_objects_and_rebases(two):
    """A material change (a new epoch) on one object never takes another object's epoch, whose
    stroke rows would then replay on the wrong object."""
    st = new_state(two.scene.spec)
    seen = {st.epoch}
    seq = 0
    for name, rebase in (("right", False), ("left", True), ("right", True), ("left", False), ("right", True)):
        seq += 1
        st, _ = apply(st, client_msg.validate_python({"seq": seq, "type": "object", "object": name}))
        if rebase:
            seq += 1
            st, _ = apply(st, client_msg.validate_python({"seq": seq, "type": "material",
                                                          "material": {"model": "lambert", "albedo": [0.3] * 3}}))
            assert st.epoch not in seen, (st.epoch, seen)
        seen.add(st.epoch)
        epochs = [e.epoch for k, e in st.edits.items() if k != st.object]
        assert st.epoch not in epochs
    with pytest.raises(StateError):
        apply(st, client_msg.validate_python({"seq": seq + 1, "type": "object", "object": "nobody"}))


def test_convert_keeps_the_objects_colour_in_the_view(two):
    rt = _runtime(two)
    rt.handle({"seq": 1, "type": "material", "material": {"model": "ggx", "alpha": 0.3, "specular": [0.3] * 3,
                                                        "albedo": [0.4, 0.2, 0.1]}})
    st = rt.state
    before = rt.renderer.render(FrameRequest(camera=st.camera, lighting=Lighting(st.rotation_deg, st.intensity),
                                             materials=st.materials))
    ev = rt.handle({"seq": 2, "type": "convert", "model": "blinn-phong"})
    assert ev[0]["type"] == "converted" and ev[0]["material"]["model"] == "blinn-phong"
    assert rt.state.material_of("left").model == "blinn-phong" and rt.state.base_material.model == "blinn-phong"
    st = rt.state
    after = rt.renderer.render(FrameRequest(camera=st.camera, lighting=Lighting(st.rotation_deg, st.intensity),
                                            materials=st.materials))
    m0 = before.radiance[before.object_id == 0].mean(axis=0)
    m1 = after.radiance[after.object_id == 0].mean(axis=0)
    assert (np.abs(m1 - m0) / m0).max() < 0.03, (m0, m1)
    assert ev[0]["curve"]["specular"] and ev[0]["curve"]["lobe"]["values"]


def test_frames_follow_the_asked_size_within_the_cap(two):
    rt = _runtime(two, max_frame_pixels=320 * 240)
    rt.handle({"seq": 1, "type": "view", "width": 300, "height": 200})
    hdr, _ = rt.frame(1)
    assert (hdr["width"], hdr["height"]) == (300, 200)
    rt.handle({"seq": 2, "type": "view", "width": 1600, "height": 1200})
    cam = rt.state.camera
    assert cam.width * cam.height <= 320 * 240 and abs(cam.width / cam.height - 4 / 3) < 0.02, cam


def test_auto_exposure_shows_the_median_object_pixel_as_middle_grey(two):
    """An uploaded scene ("exposure": "auto"): the worker exposes its first frame itself. The
    median object pixel of a full frame (another size than the one it measured) reads 0.18
    after the exposure, within 3 %; without auto the exposure stays the scene's."""
    from worker.core.tonemap import LUMA, MID_GREY

    spec = two.scene.spec.model_dump(mode="json")
    st = new_state({**spec, "exposure": "auto"})
    assert st.auto_exposure and st.exposure == 0.0
    rt = SessionRuntime(two.scene, two, {"state": st.model_dump(mode="json"), "strokes": []})
    ev = [e for e in rt.take_events() if e["type"] == "exposure"]
    assert len(ev) == 1 and ev[0]["exposure"] == rt.state.exposure and not rt.state.auto_exposure
    s = rt.state
    out = rt.renderer.render(FrameRequest(camera=s.camera.model_copy(update={"width": 320, "height": 240}),
                                          lighting=Lighting(s.rotation_deg, s.intensity), materials=s.materials,
                                          samples=4, ground_shadow=False))
    med = float(np.median((out.radiance @ LUMA)[out.object_id >= 0])) * 2 ** s.exposure
    assert abs(med / MID_GREY - 1) < 0.03, (med, s.exposure)
    assert new_state({**spec, "exposure": 1.5}).exposure == 1.5
    plain = _runtime(two)
    assert not [e for e in plain.take_events() if e["type"] == "exposure"] and plain.state.exposure == 0.0


def test_a_captured_lighting_is_applied_in_its_previews_units_and_confirmed(two, shared_assets):
    """An uploaded map (what the capture panel's Apply sends, resolved by the server to a
    preset) sets the exposure its preview was made with (the map's median luminance middle
    grey, worker/capture/pipeline.py preview_png) and says it was applied."""
    from worker.core.tonemap import LUMA, MID_GREY
    from worker.envmap import load_envmap

    path = shared_assets / "env" / "apartment.exr"
    env = load_envmap(path)
    rt = SessionRuntime(two.scene, two, {"state": new_state(two.scene.spec).model_dump(mode="json"), "strokes": []},
                        env_loader=lambda p: env)
    ev = rt.handle({"seq": 1, "type": "environment",
                    "preset": {"label": "my capture", "sha256": "0" * 64, "filename": "cap.exr"}})
    kinds = [e["type"] for e in ev]
    assert kinds == ["exposure", "note"], ev
    assert "applied" in ev[1]["message"] and "my capture" in ev[1]["message"]
    med = float(np.median(env @ LUMA))
    assert abs(med * 2 ** rt.state.exposure / MID_GREY - 1) < 0.01, (med, rt.state.exposure)


def test_a_session_left_alone_settles_on_the_anti_aliased_frame(two):
    """With no message at all after it opens, a session's thread sends its first frame (one
    sample: the view's anti-aliased primary hits are not traced yet) and then the settled,
    anti-aliased one. Before, the first frame stayed until the user nudged the view, for
    designers and shoppers alike. The thread's cache here only hands out the loaded renderer."""
    import queue

    from worker.jobs.lod import STILL_SAMPLES
    from worker.jobs.runner import SessionThread

    class _Loaded:
        def renderer(self, scene, kind=None):
            return two

        def envmap(self, f):
            raise AssertionError("no environment preset in this session")

    for readonly, eye in ((False, [0.1, 0.8, 5.2]), (True, [0.6, 0.9, 5.1])):     # each a view not traced yet
        outq = queue.Queue()
        cam = {**two.scene.spec.camera.model_dump(mode="json"), "eye": eye}
        st = new_state(two.scene.spec, camera=cam, readonly=readonly)
        th = SessionThread("s1", {"scene": {}, "state": st.model_dump(mode="json"), "strokes": []}, _Loaded(), outq)
        th.start()
        frames, deadline = [], time.monotonic() + 120
        try:
            while len(frames) < 2 and time.monotonic() < deadline:
                try:
                    r = outq.get(timeout=1)
                except queue.Empty:
                    continue
                assert r.kind != "event" or r.payload.get("type") != "error", r.payload
                if r.kind == "frame":
                    frames.append(r.payload[0])
        finally:
            th.stop()
            th.join(30)
        assert [f["samples"] for f in frames] == [1, STILL_SAMPLES], (readonly, frames)
        assert frames[0]["quick"] and not frames[1]["quick"]
