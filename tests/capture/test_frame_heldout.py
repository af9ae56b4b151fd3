"""The lens-frame detector on HDRIs its constants never saw (bench/frame_detector.py HELD_OUT:
six pmndrs HDRIs and Blender's courtyard; the constants were chosen on its TUNING HDRIs only).
Every held-out case: clean captures at three yaw pairs per HDRI, and one capture per generated
housing kind (a band with a clip arm, clip arms, a vignetting crescent, a bright polished rim),
480×320, two shots × 5 brackets, synthesised and merged once (cached, content-keyed, in
tests/.cache/frame-bench, shared with the benchmark). Clean captures must keep their circle
(the target, met); the housings' mean recall must reach the 95% target (met since regions extend
along the rim by their own factor between the shots: 0.887 → 0.967), and the bright polished
rims' on their own (before the rim pass, 0.00-0.24 of a rim was found; 0.79 before the
extension); the tuning-set tests (test_frame.py) keep the bands and clips found. Then the case the first detector failed
on, a clean 768 px capture of the hall, through the whole pipeline: it keeps its circle and
lights the bunny as well as keeping every pixel does."""
from __future__ import annotations

import numpy as np
import pytest
from helpers import cache_lock

from bench.frame_detector import HELD_OUT, TUNING, cases, merged, score

SIZE = (480, 320)
CASES = cases(HELD_OUT)
CLEAN_LOST = 0.03      # at most this share of the image circle flagged in a clean capture
RIM_RECALL = 0.95      # mean share of a held-out polished rim's pixels found (measured 0.999; 0.79 before
                       # the regions' extension by their own factor along the rim)
HOUSING_RECALL = 0.95  # mean share of every held-out housing's pixels found (the target; measured 0.967)
# at most this share of the circle flagged beyond a held-out rim (measured 4.0%, sky: its smooth
# sky beside the rim differs between the shots by the rim's own factor, and the extension takes
# it; lighting the bunny from that capture is as accurate as before, 63.7% / 63.8% diffuse, the
# clipped sun's error either way; 1.6% before the extension)
RIM_LOST = 0.05


@pytest.fixture(scope="module")
def scored(cache_dir):
    """The clean held-out cases, synthesised (cached) and scored: the housings are scored by the
    benchmark only, as nothing here asserts their recall."""
    out = []
    for case in (c for c in CASES if not c["frame"]):
        with cache_lock(str(cache_dir / "frame-bench" / case["hdri"])):
            m = merged(case, SIZE, cache_dir / "frame-bench")
        out.append(score(case, m))
    return out


@pytest.fixture(scope="module")
def scored_housings(cache_dir):
    """Every held-out capture with a housing, synthesised (cached) and scored."""
    out = []
    for case in (c for c in CASES if c["frame"]):
        with cache_lock(str(cache_dir / "frame-bench" / case["hdri"])):
            m = merged(case, SIZE, cache_dir / "frame-bench")
        out.append(score(case, m))
    return out


@pytest.fixture(scope="module")
def scored_rims(scored_housings):
    """The held-out captures with a bright polished rim."""
    return [r for r in scored_housings if r["housing"] == "rim"]


def test_held_out_housings_are_found(scored_housings):
    """All 28 held-out housings (bands, clips, vignettes, rims): the mean share of their pixels
    found, on HDRIs none of the constants (chosen on the tuning HDRIs) saw. The target is 95%."""
    assert len(scored_housings) >= 28, len(scored_housings)
    msg = "; ".join(_line(r) for r in scored_housings)
    mean = float(np.mean([r["recall"] for r in scored_housings]))
    print(f"mean recall {mean:.3f}: {msg}")
    assert mean >= HOUSING_RECALL, f"held-out housings: mean recall {mean:.3f}: " + msg


def test_the_split_is_disjoint_and_large_enough():
    assert not set(HELD_OUT) & set(TUNING)
    assert sum(1 for c in CASES if not c["frame"]) >= 20 and sum(1 for c in CASES if c["frame"]) >= 20


def _line(r):
    return (f"{r['hdri']}/{r['housing']}@{r['yaws'][0]:.0f}: lost {100 * r['lost']:.2f}%"
            + (f", recall {r['recall']:.3f}" if "recall" in r else ""))


def test_clean_held_out_captures_keep_their_circle(scored):
    clean = [r for r in scored if r["housing"] == "none"]
    assert len(clean) >= 20, len(clean)
    msg = "; ".join(_line(r) for r in clean)
    print(msg)
    assert max(r["lost"] for r in clean) <= CLEAN_LOST, "frame-free captures: " + msg


def test_held_out_polished_rims_are_found(scored_rims):
    """A polished barrel edge glints with the room's light, so darkness cannot find it: the rim
    pass (brighter than the other shot's view of the same direction, fixed to the sensor) must
    find most of it on HDRIs no constant saw, without cutting into the scene beside it."""
    assert len(scored_rims) >= 7, len(scored_rims)
    msg = "; ".join(_line(r) for r in scored_rims)
    print(msg)
    assert np.mean([r["recall"] for r in scored_rims]) >= RIM_RECALL, "held-out rims: " + msg
    assert max(r["lost"] for r in scored_rims) <= RIM_LOST, "held-out rims: " + msg


def test_clean_hall_keeps_its_light(captures, small_hdri, bunny_renderer):
    """The clean indoor capture the first detector lost 15-20% of the circle on (the hall's dark
    ceiling, at the top of both shots): two 768×512 shots × 5 brackets through the whole
    pipeline, lighting the bunny (vertex mode) no worse than keeping every pixel, by at most
    0.5% relative RMSE in the diffuse and the glossy render."""
    from worker.capture.pipeline import capture
    from worker.renderers import FrameRequest
    from worker.renderers.cuts import CutRenderer
    from worker.scene import GGX, Lambert

    c = captures.get("hall.exr", width=768, height=512, frame=False, jitter_px=1, seed=3)
    original = small_hdri("hall.exr")
    r = CutRenderer(bunny_renderer.scene, bunny_renderer.data)
    mask = r.object_mask(r.scene.spec.camera) >= 0
    mats = {"diffuse": Lambert(albedo=(0.7, 0.7, 0.7)),
            "glossy": GGX(alpha=0.2, specular=(0.9, 0.9, 0.9), albedo=(0.1, 0.1, 0.1))}

    def renders(env):
        r.set_environment(env)
        return {k: r.render(FrameRequest(camera=r.scene.spec.camera, materials=[m])).radiance[mask].astype(np.float64)
                for k, m in mats.items()}

    ref = renders(original)
    err, stats = {}, {}
    for removal in (True, False):
        res = capture(c["manifest"], width=original.shape[1], remove_frame=removal)
        got = renders(res.envmap / c["truth"]["scale"])
        err[removal] = {k: float(np.sqrt(((got[k] - ref[k]) ** 2).mean() / (ref[k] ** 2).mean())) for k in got}
        stats[removal] = res.stats
    msg = (f"hall 768×512 clean: {100 * stats[True]['frame_fraction_of_circle']:.2f}% of the circle removed; "
           f"with removal diffuse {err[True]['diffuse']:.4f} glossy {err[True]['glossy']:.4f}, keeping everything "
           f"diffuse {err[False]['diffuse']:.4f} glossy {err[False]['glossy']:.4f}")
    print(msg)
    assert stats[True]["frame_fraction_of_circle"] <= CLEAN_LOST, msg
    # the frame removal costs nothing: what error remains is the pipeline's (the hall's lamps
    # are a few pixels wide at 768 px: the guide's "lights a few pixels wide")
    assert err[True]["diffuse"] <= err[False]["diffuse"] + 0.005, msg
    assert err[True]["glossy"] <= err[False]["glossy"] + 0.005, msg
