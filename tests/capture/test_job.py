"""The service's side: safe extraction of an uploaded capture zip, and run_capture returning the
EXR, the preview PNG and the statistics."""
from __future__ import annotations

import io
import json
import stat
import zipfile

import numpy as np
import pytest

from worker.capture.job import extract_capture_zip, run_capture
from worker.capture.manifest import CaptureError


def _zip(entries: dict[str, bytes], symlinks: dict[str, str] | None = None) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in entries.items():
            z.writestr(name, data)
        for name, target in (symlinks or {}).items():
            info = zipfile.ZipInfo(name)
            info.external_attr = (stat.S_IFLNK | 0o777) << 16
            z.writestr(info, target)
    return buf.getvalue()


@pytest.fixture(scope="module")
def small(captures):
    return captures.get("sunset.exr", width=240, height=160, brackets=3, seed=7)


def _capture_entries(small, prefix="") -> dict[str, bytes]:
    return {prefix + p.name: p.read_bytes() for p in small["dir"].iterdir() if p.suffix in (".jpg", ".json")
            and p.name != "truth.json"}


def test_extract_and_run(small, tmp_path):
    """A zip of a folder (as a desktop's "compress" makes, with macOS litter) extracts and runs:
    the EXR decodes to the map, the PNG is a preview, the stats are the CLI's."""
    from PIL import Image

    from worker.envmap import load_envmap

    entries = _capture_entries(small, "my capture/")
    entries["__MACOSX/my capture/._shot0_0.jpg"] = b"junk"
    entries["my capture/.DS_Store"] = b"junk"
    m = extract_capture_zip(_zip(entries), tmp_path / "x", max_files=16, max_total_bytes=10 << 20)
    assert m == tmp_path / "x" / "my capture" / "manifest.json"
    assert not (tmp_path / "x" / "__MACOSX").exists()
    seen = []
    exr, png, stats = run_capture(m, lambda f, msg: seen.append(f), width=256)
    (tmp_path / "env.exr").write_bytes(exr)
    env = load_envmap(tmp_path / "env.exr")
    assert env.shape == (128, 256, 3) and np.isfinite(env).all() and env.max() > 0
    img = Image.open(io.BytesIO(png))
    assert img.format == "PNG" and img.size == (256, 128)
    assert {"seconds", "dynamic_range_stops", "frame_pixels_removed", "response"} <= stats.keys()
    assert seen[0] == 0.0 and seen[-1] == 1.0 and all(b >= a for a, b in zip(seen, seen[1:]))
    json.dumps(stats)                                               # JSON-able as the job's result


@pytest.mark.parametrize("name,match", [
    ("../evil.jpg", r"outside the archive's root"),
    ("a/../../evil.jpg", r"outside the archive's root"),
    ("/etc/evil.jpg", "absolute paths"),
    ("C:/evil.jpg", "absolute paths"),
    ("a\\..\\evil.jpg", "backslashes"),
])
def test_paths_outside_root_are_refused(small, tmp_path, name, match):
    entries = _capture_entries(small)
    entries[name] = b"x"
    with pytest.raises(CaptureError, match=match) as e:
        extract_capture_zip(_zip(entries), tmp_path / "x", 16, 10 << 20)
    assert e.value.status == 400
    assert not any((tmp_path / "x").rglob("*")) if (tmp_path / "x").exists() else True
    assert not (tmp_path / "evil.jpg").exists()


def test_symlinks_are_refused(small, tmp_path):
    with pytest.raises(CaptureError, match="symbolic links"):
        extract_capture_zip(_zip(_capture_entries(small), {"link.jpg": "/etc/passwd"}), tmp_path / "x", 16, 10 << 20)


def test_limits(small, tmp_path):
    entries = _capture_entries(small)
    with pytest.raises(CaptureError, match="more than 3 files") as e:
        extract_capture_zip(_zip(entries), tmp_path / "a", max_files=3, max_total_bytes=10 << 20)
    assert e.value.status == 413
    with pytest.raises(CaptureError, match="unpacks to more than 1000 bytes") as e:
        extract_capture_zip(_zip(entries), tmp_path / "b", max_files=16, max_total_bytes=1000)
    assert e.value.status == 413


def test_zip_bomb(tmp_path):
    """100 MB of zeros deflate to ~100 KB: refused from the declared size before writing."""
    bomb = _zip({"manifest.json": b"{}", "zeros.jpg": bytes(100 << 20)})
    assert len(bomb) < 1 << 20
    with pytest.raises(CaptureError, match="unpacks to more than") as e:
        extract_capture_zip(bomb, tmp_path / "x", 16, 10 << 20)
    assert e.value.status == 413
    assert not (tmp_path / "x" / "zeros.jpg").exists()


def test_lying_header(tmp_path):
    """An entry whose header declares fewer bytes than it holds is caught while extracting."""
    raw = bytearray(_zip({"manifest.json": b"{}", "a.jpg": bytes(5000)}))
    # shrink a.jpg's declared size in both its local header and the central directory
    for sig, off in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
        i = -1
        while (i := raw.find(sig, i + 1)) >= 0:
            name_len_at = 26 if sig == b"PK\x03\x04" else 28
            n = int.from_bytes(raw[i + name_len_at:i + name_len_at + 2], "little")
            name_at = i + (30 if sig == b"PK\x03\x04" else 46)
            if raw[name_at:name_at + n] == b"a.jpg":
                raw[i + off:i + off + 4] = (100).to_bytes(4, "little")
    with pytest.raises(CaptureError, match="a.jpg"):
        extract_capture_zip(bytes(raw), tmp_path / "x", 16, 10 << 20)


def test_bad_archives(tmp_path, small):
    with pytest.raises(CaptureError, match="not a zip archive"):
        extract_capture_zip(b"PK but not really", tmp_path / "a", 16, 1 << 20)
    with pytest.raises(CaptureError, match=r"no capture manifest \(.json\)"):
        extract_capture_zip(_zip({"a.jpg": b"x"}), tmp_path / "b", 16, 1 << 20)
    with pytest.raises(CaptureError, match="several manifests"):
        extract_capture_zip(_zip({"a.json": b"{}", "b.json": b"{}"}), tmp_path / "c", 16, 1 << 20)
    with pytest.raises(CaptureError, match="appears twice"):
        extract_capture_zip(_zip({"manifest.json": b"{}", "A.jpg": b"1", "a.jpg": b"2"}), tmp_path / "d", 16, 1 << 20)
    # manifest.json wins over other JSON files
    m = extract_capture_zip(_zip({"manifest.json": b"{}", "notes.json": b"{}"}), tmp_path / "e", 16, 1 << 20)
    assert m.name == "manifest.json"


def test_run_capture_is_confined_to_the_upload(small, tmp_path):
    """A manifest inside an upload that names a file outside it is refused, not read."""
    entries = _capture_entries(small)
    man = json.loads(entries["manifest.json"])
    man["shots"][0]["images"][0]["file"] = "../../../../etc/hostname"
    entries["manifest.json"] = json.dumps(man).encode()
    m = extract_capture_zip(_zip(entries), tmp_path / "x", 16, 10 << 20)
    with pytest.raises(CaptureError, match="outside the capture folder"):
        run_capture(m)
