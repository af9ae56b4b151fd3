"""HDR per shot: bracket alignment, response recovery and the merge, each checked against the
synthetic camera's truth, the C merge against its NumPy reference, and both against OpenCV's
(AlignMTB, MergeDebevec) on the same photos."""
from __future__ import annotations

import numpy as np
import pytest

from worker import native
from worker.native.kernels import kernels
from worker.capture import hdr
from worker.capture.fisheye import Lens
from worker.capture.manifest import load_capture
from worker.capture.synth import inverse_camera_curve, synthesize

LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


def _shot(cap, lens, i):
    photos = cap.shots[i]
    st = hdr.read_bracket(photos, cap.width, cap.height)
    ex = np.array([p.exposure for p in photos])
    return st, ex


@pytest.mark.parametrize("hdri", ["sunset.exr", "apartment.exr", "lobby.exr"])
def test_response_matches_the_camera(captures, hdri):
    """The recovered inverse response equals the synthetic camera's (normalised at mid-grey)
    within 0.1 stops RMS over pixel values 16..240 in every channel."""
    c = captures.get(hdri, jitter_px=2, seed=0)
    cap = load_capture(c["manifest"])
    lens = Lens(cap.width, cap.height, cap.manifest.projection, cap.manifest.fov_deg)
    _, resp = hdr.merge_capture(cap, lens)
    z = np.arange(16, 241)
    true = inverse_camera_curve(z / 255.0)
    true = true / inverse_camera_curve(128 / 255.0) * hdr.MID_GREY
    err = np.sqrt(np.mean(np.log2(resp.lin[z] / true[:, None]) ** 2, axis=0))
    assert (err < 0.1).all(), f"{hdri}: response error {err.round(3)} stops RMS (R, G, B)"
    assert resp.monotone_fixes < 20, resp.summary()


def test_debevec_solver_matches_opencv(captures):
    """Our sparse solve of the Debevec-Malik system equals OpenCV's CalibrateDebevec (dense SVD)
    on the same samples."""
    c = captures.get("sunset.exr", jitter_px=2, seed=0)
    cap = load_capture(c["manifest"])
    lens = Lens(cap.width, cap.height, cap.manifest.projection, cap.manifest.fov_deg)
    inner = lens.pixel_radius() <= 0.9 * lens.radius
    samples = []
    for i in range(len(cap.shots)):
        st, ex = _shot(cap, lens, i)
        valid, _ = hdr.align_bracket(st, lens, ex)
        samples.append((hdr.select_samples(st, valid, inner, 128, np.random.default_rng(i)), ex))
    ours = hdr.calibrate(samples, 100.0)
    ref = hdr.calibrate(samples, 100.0, use_opencv=True)
    z = np.arange(16, 241)
    d = np.abs(np.log2(ours.lin[z] / ref.lin[z])).max()
    # OpenCV solves in float32 by SVD: it drifts by up to ~0.02 stops (more at the unconstrained
    # ends, z < 16), which is why the comparison stops at 16..240
    assert d < 0.03, f"max |log2 ratio| {d:.2e} between our solve and OpenCV's over z = 16..240"


def test_alignment_recovers_hand_shake(captures):
    """Synthetic hand-held brackets (scene shifted by up to ±2 px per bracket, frame fixed):
    our alignment finds the shifts; OpenCV's AlignMTB (median thresholds over the whole frame)
    on the same brackets does worse, which is why we threshold on the common range."""
    import cv2

    found_ok = cv_ok = total = 0
    for hdri in ("sunset.exr", "lobby.exr"):
        c = captures.get(hdri, jitter_px=2, seed=0)
        cap = load_capture(c["manifest"])
        lens = Lens(cap.width, cap.height, cap.manifest.projection, cap.manifest.fov_deg)
        truth = c["truth"]["scene_shifts_px"]
        for i in range(len(cap.shots)):
            st, ex = _shot(cap, lens, i)
            ref = len(ex) // 2
            greys = [hdr._grey(s) for s in st]
            _, shifts = hdr.align_bracket(st.copy(), lens, ex)
            mtb = cv2.createAlignMTB(3, 4, True)
            for k in range(len(ex)):
                if k == ref:
                    continue
                t = truth[i * len(ex) + k]
                want = (-t[0] + truth[i * len(ex) + ref][0], -t[1] + truth[i * len(ex) + ref][1])
                total += 1
                found_ok += tuple(shifts[k]) == want
                cv_ok += tuple(int(v) for v in mtb.calculateShift(greys[ref], greys[k])) == want
    assert found_ok >= 0.8 * total, f"alignment exact for {found_ok}/{total} brackets (OpenCV MTB: {cv_ok})"
    assert found_ok > cv_ok, f"ours {found_ok}/{total}, OpenCV AlignMTB {cv_ok}/{total}"


def test_merge_c_matches_numpy(captures):
    assert native.available(), "C kernels not built (make install)"
    c = captures.get("lobby.exr", jitter_px=2, seed=0)
    cap = load_capture(c["manifest"])
    lens = Lens(cap.width, cap.height, cap.manifest.projection, cap.manifest.fov_deg)
    st, ex = _shot(cap, lens, 0)
    valid, _ = hdr.align_bracket(st, lens, ex)
    valid &= lens.circle_mask()[None]
    resp = hdr.Response(np.stack([inverse_camera_curve(np.arange(256) / 255.0)] * 3, axis=1) + 1e-6, 0, 0.0)
    val, wt = hdr.merge_tables(resp, ex)
    a, sa = hdr.merge(st, valid, val, wt, kernels("native"))
    b, sb = hdr.merge(st, valid, val, wt, kernels("numpy"))
    np.testing.assert_allclose(a, b, rtol=2e-5, atol=1e-30)
    assert (sa == sb).all()
    assert set(np.unique(sa)) >= {0, 4}                   # merged pixels and the outside of the circle


@pytest.mark.parametrize("hdri", ["sunset.exr", "lobby.exr", "stinson-beach.hdr"])
def test_merge_beats_opencv_merge_debevec(tmp_path, small_hdri, hdri):
    """Against the radiance the sensor saw, with the same response: on pixels some bracket
    exposes properly, our merge's log-luminance error is on par with OpenCV's MergeDebevec's
    (never 5% above it), and its energy over the image circle is at least as close (the merge
    exists for what OpenCV's cannot take: invalid pixels and a defined clipped fallback). Where the sun clips in every bracket
    (stinson-beach with a phone's ±3 EV ladder) both lose most of its energy (the capture
    reports the clipped fraction)."""
    sc = synthesize(small_hdri(hdri), tmp_path / "c", frame=False, seed=1)
    cap = load_capture(sc.manifest)
    lens = Lens(cap.width, cap.height, cap.manifest.projection, cap.manifest.fov_deg)
    shots, resp = hdr.merge_capture(cap, lens)
    e_ref = hdr.reference_exposure(cap)
    inside = lens.circle_mask()
    sa = lens.pixel_solid_angle()[inside]
    msg, worse = [], []
    for i, shot in enumerate(shots):
        truth = (sc.radiance[i] @ LUMA)[inside] * sc.scale
        measured = (shot.status[inside] == 0) & (truth > 0)
        st, ex = _shot(cap, lens, i)
        cvm = hdr.merge_opencv(st, ex / e_ref, resp)
        errs = {}
        for name, img in (("ours", shot.radiance), ("opencv", cvm)):
            lum = (img @ LUMA)[inside]
            d = np.log2(np.maximum(lum[measured], 1e-12) / truth[measured])
            errs[name] = (float(np.sqrt(np.average(d ** 2, weights=sa[measured]))),
                          float((lum * sa).sum() / (truth * sa).sum()))
        msg.append(f"shot {i}: ours log-RMS {errs['ours'][0]:.3f} stops, energy ×{errs['ours'][1]:.3f}; "
                   f"OpenCV {errs['opencv'][0]:.3f} stops, ×{errs['opencv'][1]:.3f}; "
                   f"{100 * (1 - measured.mean()):.2f}% of the circle unmeasured")
        worse.append(errs["ours"][0] > 1.05 * errs["opencv"][0] or
                     abs(np.log(errs["ours"][1])) > abs(np.log(errs["opencv"][1])) + 0.01)
    assert not any(worse), f"{hdri}: " + "; ".join(msg)
