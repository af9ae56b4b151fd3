"""The worker-side session, without a server: replay after a crash and the per-vertex transfer
that makes stroke frames cheap."""
import numpy as np

from worker.jobs.session import SessionRuntime, brdf_curve, decode_frame, encode_frame
from worker.scene import GGX, Lambert

STROKE = {"points": [[62, 62], [88, 64]], "color": [4.0, 4.0, 4.0], "diameter": 10, "kappa": 0.05}


def _runtime(bunny, strokes=()):
    scene, cuts = bunny
    return SessionRuntime(scene, cuts, {"materials": [Lambert(albedo=(0.4, 0.4, 0.4)).model_dump()]}, list(strokes))


def test_stroke_frame_uses_the_vertex_transfer(bunny):
    rt = _runtime(bunny)
    rt.apply({"seq": 1, "type": "stroke", "stroke": STROKE})
    ev = rt.fit_if_needed()
    assert ev[0]["type"] == "fit" and ev[0]["stats"]["painted"] > 0
    ov = rt._override()
    assert ov is not None
    fast = rt.engine.render(rt.camera, rt.rotation, rt.intensity, vertex_override=ov)
    slow = rt.engine.render(rt.camera, rt.rotation, rt.intensity)
    obj = rt.engine.object_mask(rt.camera) == 0
    rel = np.sqrt(((fast - slow)[obj] ** 2).mean()) / np.sqrt((slow[obj] ** 2).mean())
    assert rel < 0.02, rel          # exact SRBF sum against the renderer's p(h) table
    # a view change invalidates it (the renderer shades again)
    rt.apply({"seq": 2, "type": "view", "eye": [0.5, 0.6, 3.1]})
    assert rt._override() is None


def test_replay_rebuilds_the_same_design(bunny):
    rt = _runtime(bunny)
    rt.apply({"seq": 1, "type": "stroke", "stroke": STROKE})
    rt.apply({"seq": 2, "type": "light", "rotation_deg": 40})
    rt.apply({"seq": 3, "type": "stroke", "stroke": {**STROKE, "points": [[50, 80], [70, 82]], "color": [-1, -1, -1]}})
    rt.apply({"seq": 4, "type": "undo"})
    rt.fit_if_needed()
    a = np.asarray(rt.materials[0].coefficients)
    # what the server persists: each stroke with the view and light it was painted in, and its flag
    cam = rt.camera.model_dump()
    recs = [{"stroke": STROKE, "camera": cam, "rotation_deg": 0.0, "intensity": 1.0, "undone": False},
            {"stroke": {**STROKE, "points": [[50, 80], [70, 82]], "color": [-1, -1, -1]}, "camera": cam,
             "rotation_deg": 40.0, "intensity": 1.0, "undone": True}]
    again = _runtime(bunny, recs)
    again.rotation = 40.0
    again.fit_if_needed()
    np.testing.assert_allclose(np.asarray(again.materials[0].coefficients), a, rtol=1e-6, atol=1e-9)
    assert again.fitter.history.can_redo and len(again.fitter.history) == 1


def test_frame_encoding_and_curves():
    hdr = {"frame": 3, "ack": 7, "width": 2, "height": 1, "format": "jpeg"}
    h, img = decode_frame(encode_frame(hdr, b"\xff\xd8jpeg"))
    assert h == hdr and img == b"\xff\xd8jpeg"
    c = brdf_curve(GGX(alpha=0.2, specular=(0.5, 0.5, 0.5)))
    v = np.asarray(c["values"])
    assert len(c["theta_deg"]) == len(v) and v[0, 0] > v[30, 0] > 0     # falls off from the peak
