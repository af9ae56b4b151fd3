"""The capture pipeline end to end: photos synthesised from real HDRIs (fisheye views by the documented
projection, a filmic camera curve, 8-bit JPEG brackets with EXIF exposure times, hand shake,
a painted lens frame) go through the whole capture path, and the recovered map lights Glint's
own renderer (the bunny, the cut renderer of tests/scenes/bunny.json) like the original:
diffuse and glossy renders within 5% relative RMSE. The same capture without frame removal
is rendered too, to show what the removal buys. The map's log-luminance error is reported.

No scale is fitted: the recovered map is divided by the scale the exposure bookkeeping
predicts (synth.py: t_ref · MID_GREY / X₁₂₈), and that prediction is itself checked.

Photo sizes: 600×400 where the scene's lights span enough pixels; lobby (small ceiling lamps)
and forest (sun through leaves) at 1200×800, because JPEG's 8×8 blocks flatten lights only a
few pixels wide and lose their energy (at 600×400 these two are at 4-6%; README)."""
from __future__ import annotations

import numpy as np
import pytest

from worker.capture.pipeline import capture
from worker.capture.stitch import row_solid_angle
from worker.renderers import FrameRequest
from worker.renderers.cuts import CutRenderer
from worker.scene import GGX, Lambert

LUMA = np.array([0.2126, 0.7152, 0.0722])
CASES = [("sunset.exr", 600, 400), ("apartment.exr", 600, 400), ("city.exr", 600, 400),
         ("lobby.exr", 1200, 800), ("forest.exr", 1200, 800)]
MATERIALS = {"diffuse": Lambert(albedo=(0.7, 0.7, 0.7)),
             "glossy": GGX(alpha=0.2, specular=(0.9, 0.9, 0.9), albedo=(0.1, 0.1, 0.1))}


@pytest.fixture(scope="module")
def engine(bunny_renderer):
    r = CutRenderer(bunny_renderer.scene, bunny_renderer.data)       # its own light, shared cuts
    return r, r.object_mask(r.scene.spec.camera) >= 0


def _renders(engine, env) -> dict:
    r, mask = engine
    r.set_environment(env)
    out = {}
    for name, m in MATERIALS.items():
        out[name] = r.render(FrameRequest(camera=r.scene.spec.camera, materials=[m])).radiance[mask].astype(np.float64)
    return out


def _rel_rmse(a, b) -> float:
    return float(np.sqrt(((a - b) ** 2).mean() / (b ** 2).mean()))


def _log_lum_rms(rec, ref) -> float:
    """Solid-angle weighted RMS of log₂ luminance ratio (stops) over the sphere."""
    w = np.broadcast_to(row_solid_angle(*ref.shape[:2])[:, None], ref.shape[:2])
    a, b = rec @ LUMA, ref @ LUMA
    ok = b > 0
    d = np.log2(np.maximum(a[ok], 1e-12) / b[ok])
    return float(np.sqrt(np.average(d ** 2, weights=w[ok])))


@pytest.mark.parametrize("hdri,width,height", CASES)
def test_recovered_map_lights_like_the_original(captures, small_hdri, engine, hdri, width, height):
    c = captures.get(hdri, width=width, height=height, jitter_px=2, seed=0)
    original = small_hdri(hdri)
    ref = _renders(engine, original)
    res = {}
    for removal in (True, False):
        r = capture(c["manifest"], width=original.shape[1], remove_frame=removal)
        rec = r.envmap / c["truth"]["scale"]
        got = _renders(engine, rec)
        res[removal] = {k: _rel_rmse(got[k], ref[k]) for k in got} | {"log_lum_rms": _log_lum_rms(rec, original),
                                                                      "stats": r.stats}
        if removal:
            ratio = float(np.exp(np.median(np.log(np.maximum(rec @ LUMA, 1e-12) / np.maximum(original @ LUMA, 1e-12)))))
    on, off = res[True], res[False]
    report = (f"{hdri} {width}×{height}: with frame removal diffuse {on['diffuse']:.4f}, glossy {on['glossy']:.4f}, "
              f"log-luminance RMS {on['log_lum_rms']:.3f} stops, frame {on['stats']['frame_pixels_removed']} px "
              f"(truth {int(c['frame'].sum())}), inpainted {on['stats']['inpainted_fraction_of_sphere']:.4f} of the sphere; "
              f"without: diffuse {off['diffuse']:.4f}, glossy {off['glossy']:.4f}, "
              f"log-luminance RMS {off['log_lum_rms']:.3f} stops; median scale ratio {ratio:.3f}")
    print(report)
    assert on["diffuse"] < 0.05 and on["glossy"] < 0.05, report
    assert on["diffuse"] + on["glossy"] < off["diffuse"] + off["glossy"], "frame removal did not help: " + report
    assert on["log_lum_rms"] < off["log_lum_rms"], report
    assert abs(ratio - 1.0) < 0.05, "exposure bookkeeping off: " + report
    st = on["stats"]
    for key in ("seconds", "dynamic_range_stops", "frame_pixels_removed", "response"):
        assert key in st
    assert st["frame_pixels_removed"] >= c["frame"].sum()
    assert st["exposure_notes"] == [], st["exposure_notes"]          # the EXIF is right: no alarm
    assert st["dynamic_range_stops"] > 8


@pytest.mark.parametrize("projection,fov", [("equidistant", 190.0), ("equisolid", 200.0)])
def test_no_frame_nothing_removed(captures, small_hdri, engine, projection, fov):
    """A clean capture (no lens frame) loses nothing to the detector and stitches seamlessly,
    with either projection."""
    c = captures.get("apartment.exr", frame=False, jitter_px=2, seed=5, projection=projection, fov_deg=fov)
    r = capture(c["manifest"], width=512)
    assert r.stats["frame_pixels_removed"] == 0
    assert r.stats["inpainted_fraction_of_sphere"] == 0.0
    assert abs(r.stats["exposure_gains_stops"][0]) < 0.05, r.stats["exposure_gains_stops"]
    assert r.stats["overlap_deg"] == pytest.approx(fov - 180.0)
    original = small_hdri("apartment.exr")
    rec = r.envmap / c["truth"]["scale"]
    err = _log_lum_rms(rec, original)
    got, ref = _renders(engine, rec), _renders(engine, original)
    rr = {k: _rel_rmse(got[k], ref[k]) for k in got}
    assert err < 0.15 and max(rr.values()) < 0.02, f"{projection}: log-luminance RMS {err:.3f} stops, renders {rr}"


def test_exposure_matching_between_shots(captures, tmp_path):
    """The back shot's EXIF claims half its real exposure time (a phone's rounding, or a lie):
    exposure matching finds the 1-stop gap from the overlap and splits it between the shots."""
    import json
    import shutil

    from PIL import ExifTags, Image, TiffImagePlugin

    c = captures.get("sunset.exr", frame=False, seed=6)
    d = tmp_path / "cap"
    shutil.copytree(c["dir"], d)
    m = json.loads((d / "manifest.json").read_text())
    for im in m["shots"][1]["images"]:
        f = d / im["file"]
        img = Image.open(f)
        ex = img.getexif()
        sub = ex.get_ifd(ExifTags.IFD.Exif)
        t = float(sub[ExifTags.Base.ExposureTime]) / 2
        sub[ExifTags.Base.ExposureTime] = TiffImagePlugin.IFDRational(t)
        img.save(f, quality=95, exif=ex)
    r = capture(d / "manifest.json", width=512)
    g = r.stats["exposure_gains_stops"]
    assert g[1] - g[0] == pytest.approx(-1.0, abs=0.1), g


def test_mistyped_exposure_is_flagged(captures, tmp_path):
    """A designer types one bracket's exposure_s 4× too long: the capture still runs and its
    notes name the photo whose pixels disagree with the numbers."""
    import json
    import shutil

    c = captures.get("city.exr", frame=False, seed=8)
    d = tmp_path / "cap"
    shutil.copytree(c["dir"], d)
    m = json.loads((d / "manifest.json").read_text())
    for s in m["shots"]:
        for t, im in zip(c["truth"]["shutter_s"], s["images"]):
            im["exposure_s"] = t
    m["shots"][1]["images"][3]["exposure_s"] *= 4
    (d / "manifest.json").write_text(json.dumps(m))
    notes = capture(d / "manifest.json", width=256).stats["exposure_notes"]
    assert notes and all("shot1_3.jpg" in n for n in notes), notes
    assert "check exposure_s" in notes[0]
