"""Capture manifest v1: the schema, exposures from the manifest or EXIF, and clear errors for
bad input (missing brackets, inconsistent sizes, unknown projection, no exposure information)."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from PIL import Image

from worker.capture.manifest import CaptureError, load_capture, parse_manifest


@pytest.fixture(scope="module")
def small(captures):
    return captures.get("apartment.exr", width=240, height=160, brackets=3, seed=3)


def _copy(src, tmp_path, edit=None):
    d = tmp_path / "cap"
    shutil.copytree(src["dir"], d)
    m = json.loads((d / "manifest.json").read_text())
    if edit:
        edit(m, d)
    (d / "manifest.json").write_text(json.dumps(m))
    return d / "manifest.json"


def test_schema_is_the_issue_json():
    m = parse_manifest({"version": 1, "projection": "equidistant", "fov_deg": 190,
                        "shots": [{"yaw_deg": 0, "images": [{"file": "front_0.jpg", "exposure_s": 0.004},
                                                             {"file": "front_1.jpg", "exposure_s": 0.016}]},
                                  {"yaw_deg": 180, "images": [{"file": "back_0.jpg"}, {"file": "back_1.jpg"}]}]})
    assert m.shots[1].images[0].exposure_s is None
    with pytest.raises(CaptureError, match="unknown projection 'stereographic'"):
        parse_manifest({"version": 1, "projection": "stereographic", "fov_deg": 190, "shots": m.model_dump()["shots"]})
    with pytest.raises(CaptureError, match="version"):
        parse_manifest({"version": 2, "projection": "equisolid", "fov_deg": 190, "shots": m.model_dump()["shots"]})
    with pytest.raises(CaptureError, match="fov_deg"):
        parse_manifest({"version": 1, "projection": "equisolid", "fov_deg": -5, "shots": m.model_dump()["shots"]})
    with pytest.raises(CaptureError, match="exposure_s"):
        parse_manifest({"version": 1, "projection": "equisolid", "fov_deg": 190,
                        "shots": [{"yaw_deg": 0, "images": [{"file": "a.jpg", "exposure_s": 0}, {"file": "b.jpg"}]}]})
    with pytest.raises(CaptureError, match="pitch_deg: Extra inputs"):
        parse_manifest({"version": 1, "projection": "equisolid", "fov_deg": 190, "pitch_deg": 3,
                        "shots": m.model_dump()["shots"]})


def test_exposures_from_exif(small):
    """The synthetic photos carry ExposureTime, FNumber 2.0 and ISO 100 in EXIF only."""
    cap = load_capture(small["manifest"])
    t = np.array(small["truth"]["shutter_s"])
    for shot in cap.shots:
        got = np.array([p.exposure for p in shot])
        assert all(p.shutter_source == "exif" for p in shot)
        np.testing.assert_allclose(got, t * (100 / 100) / 2.0 ** 2, rtol=1e-6)
    assert (cap.width, cap.height) == (240, 160)


def test_exposure_s_overrides_exif(small, tmp_path):
    def edit(m, d):
        for s in m["shots"]:
            for k, im in enumerate(s["images"]):
                im["exposure_s"] = 0.001 * 4 ** k
    cap = load_capture(_copy(small, tmp_path, edit))
    np.testing.assert_allclose([p.exposure for p in cap.shots[0]], [0.001 * 4 ** k / 4 for k in range(3)], rtol=1e-9)
    assert {p.shutter_source for s in cap.shots for p in s} == {"manifest"}


def test_missing_bracket_file(small, tmp_path):
    def edit(m, d):
        (d / m["shots"][1]["images"][2]["file"]).unlink()
    with pytest.raises(CaptureError, match=r"shots\[1\]\.images\[2\]\.file.*not found"):
        load_capture(_copy(small, tmp_path, edit))


def test_single_image_is_not_a_bracket(small, tmp_path):
    def edit(m, d):
        m["shots"][0]["images"] = m["shots"][0]["images"][:1]
    with pytest.raises(CaptureError, match="shot 0 .* 1 image.*at least 2 exposures"):
        load_capture(_copy(small, tmp_path, edit))


def test_equal_exposures_are_not_a_bracket(small, tmp_path):
    def edit(m, d):
        for im in m["shots"][0]["images"]:
            im["exposure_s"] = 0.01
    with pytest.raises(CaptureError, match=r"shots\[0\].*same exposure"):
        load_capture(_copy(small, tmp_path, edit))


def test_inconsistent_sizes(small, tmp_path):
    def edit(m, d):
        f = d / m["shots"][1]["images"][0]["file"]
        Image.open(f).resize((200, 160)).save(f, exif=Image.open(f).getexif())
    with pytest.raises(CaptureError, match=r"shots\[1\]\.images\[0\].*200×160 but .* 240×160"):
        load_capture(_copy(small, tmp_path, edit))


def test_no_exposure_information(small, tmp_path):
    def edit(m, d):
        f = d / m["shots"][0]["images"][1]["file"]
        Image.open(f).save(f, quality=95)           # re-saved without EXIF
    with pytest.raises(CaptureError, match=r"shots\[0\]\.images\[1\].*no exposure information.*exposure_s"):
        load_capture(_copy(small, tmp_path, edit))


def test_iso_ignored_unless_every_photo_has_it(small, tmp_path):
    """A photo without EXIF but with exposure_s: ISO and FNumber are dropped for all photos, so
    exposures stay comparable, and the capture says so."""
    def edit(m, d):
        im = m["shots"][0]["images"][1]
        f = d / im["file"]
        Image.open(f).save(f, quality=95)
        im["exposure_s"] = small["truth"]["shutter_s"][1]
    cap = load_capture(_copy(small, tmp_path, edit))
    np.testing.assert_allclose([p.exposure for p in cap.shots[0]], small["truth"]["shutter_s"], rtol=1e-6)
    assert "ISO ignored: not every photo has it" in cap.exposure_notes
    assert "FNumber ignored: not every photo has it" in cap.exposure_notes


def test_not_json(tmp_path):
    p = tmp_path / "m.json"
    p.write_text("{not json")
    with pytest.raises(CaptureError, match="not a JSON file"):
        load_capture(p)
    with pytest.raises(CaptureError, match="not found"):
        load_capture(tmp_path / "absent.json")


def test_confined_to_root(small, tmp_path):
    """With a root (the service), a manifest cannot read files outside its folder."""
    outside = tmp_path / "secret.jpg"
    shutil.copy(small["dir"] / "shot0_0.jpg", outside)

    def edit(m, d):
        m["shots"][0]["images"][0]["file"] = "../secret.jpg"
    path = _copy(small, tmp_path, edit)
    load_capture(path)                                     # the CLI may read beside the manifest
    with pytest.raises(CaptureError, match="outside the capture folder"):
        load_capture(path, root=path.parent)


def test_shots_must_cover_the_sphere(small, tmp_path):
    """One 190° shot sees half the sphere: refused before any photo is decoded."""
    from worker.capture.pipeline import capture

    def edit(m, d):
        m["shots"] = m["shots"][:1]
    with pytest.raises(CaptureError, match=r"cover only 5\d\.\d% of the sphere.*fov_deg 190"):
        capture(_copy(small, tmp_path, edit))
