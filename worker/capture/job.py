"""The service's side of a capture: an uploaded zip (the manifest and its photos) → the
environment map, its preview and statistics.

The REST contract (implemented by the server, which calls these two functions in a worker):

- ``POST /v1/captures``, body a zip (``Content-Type: application/zip``) of ``manifest.json``
  (any single ``.json``; ``manifest.json`` wins when there are several) and the photos it names,
  within the upload limits → 202 ``{"id", "status", "progress"}``;
- ``GET /v1/captures/{id}`` → ``{"id", "status": "queued|running|done|failed", "progress": 0..1,
  "message", "asset_id" (the environment-map asset, once done), "stats"}``;
- ``GET /v1/captures/{id}/preview`` → PNG;
- the studio then sends the stream message ``{"type": "environment", "asset_id": …}``.

Zip safety (``extract_capture_zip``): only regular files with relative names are extracted,
never outside the destination: absolute names, drive letters, backslashes, ``..`` components,
symlinks, encrypted entries and duplicate names are refused with a message naming the entry.
The number of files and the total size are bounded by the caller's limits from the *declared*
sizes before anything is written (a zip bomb declares its real size or is caught by the next
check), and by the bytes actually written while extracting (a lying header). macOS's
``__MACOSX/`` and ``.DS_Store`` entries, which a Finder "Compress" adds, are skipped.
"""
from __future__ import annotations

import io
import stat
import zipfile
from pathlib import Path, PurePosixPath

from .manifest import CaptureError

CHUNK = 1 << 20
# A zip bomb inflates a small upload a thousandfold (1 MiB of zip: 1 GiB of zeros). Photos and
# manifests compress far less than 100:1; an entry may unpack past that ratio only up to
# RATIO_FREE bytes (small files of repetitive text are harmless)
MAX_RATIO = 100
RATIO_FREE = 1 << 20


def _is_junk(name: str) -> bool:
    parts = PurePosixPath(name).parts
    return bool(parts) and (parts[0] == "__MACOSX" or parts[-1] == ".DS_Store" or parts[-1].startswith("._"))


def _check_name(info: zipfile.ZipInfo) -> PurePosixPath:
    name = info.filename
    if "\\" in name:
        raise CaptureError(f"zip entry {name!r}: backslashes in names are not allowed (use '/')", status=400)
    if name.startswith("/") or (len(name) > 1 and name[1] == ":"):
        raise CaptureError(f"zip entry {name!r}: absolute paths are not allowed", status=400)
    p = PurePosixPath(name)
    if any(part == ".." for part in p.parts):
        raise CaptureError(f"zip entry {name!r}: points outside the archive's root ('..')", status=400)
    if not p.parts or any(part in ("", ".") for part in p.parts):
        raise CaptureError(f"zip entry {name!r}: empty path component", status=400)
    mode = info.external_attr >> 16
    if stat.S_ISLNK(mode):
        raise CaptureError(f"zip entry {name!r}: symbolic links are not allowed", status=400)
    if stat.S_IFMT(mode) not in (0, stat.S_IFREG, stat.S_IFDIR):     # 0: no type recorded (Windows, Python)
        raise CaptureError(f"zip entry {name!r}: only regular files are allowed", status=400)
    if info.flag_bits & 0x1:
        raise CaptureError(f"zip entry {name!r}: encrypted entries are not supported", status=400)
    return p


def _allowed(info: zipfile.ZipInfo, max_ratio: float) -> int:
    """Bytes an entry may unpack to: MAX_RATIO × its compressed size (at least RATIO_FREE)."""
    return max(RATIO_FREE, int(max_ratio * info.compress_size))


def extract_capture_zip(zip_bytes_or_path: bytes | str | Path, dest: str | Path, max_files: int = 64,
                        max_total_bytes: int = 512 * 1024 * 1024, max_ratio: float = MAX_RATIO) -> Path:
    """Safely extract an uploaded capture zip into ``dest`` (created; should be empty) and
    return the path of its manifest.

    Sizes are checked twice: as the zip's directory declares them, before anything is written,
    and as the bytes come out of the decompressor (declared sizes can lie): at most
    ``max_total_bytes`` in all, and per entry at most ``max_ratio`` × its compressed size.

    Raises CaptureError (status 400 for a malformed or unsafe archive, 413 for one over the
    limits, 422 when the manifest is missing or ambiguous) naming the offending entry."""
    dest = Path(dest)
    src = io.BytesIO(zip_bytes_or_path) if isinstance(zip_bytes_or_path, (bytes, bytearray, memoryview)) else zip_bytes_or_path
    try:
        zf = zipfile.ZipFile(src)
    except zipfile.BadZipFile:
        raise CaptureError("the upload is not a zip archive", status=400) from None
    except FileNotFoundError:
        raise CaptureError(f"{zip_bytes_or_path}: zip file not found", status=400) from None
    with zf:
        entries, seen, declared = [], set(), 0
        for info in zf.infolist():
            if _is_junk(info.filename):
                continue
            p = _check_name(info)
            if info.is_dir():
                continue
            key = p.as_posix().lower()                     # also catches case-only clashes
            if key in seen:
                raise CaptureError(f"zip entry {info.filename!r} appears twice", status=400)
            seen.add(key)
            entries.append((info, p))
            declared += info.file_size
            if len(entries) > max_files:
                raise CaptureError(f"the zip holds more than {max_files} files", status=413)
            if declared > max_total_bytes:
                raise CaptureError(f"the zip unpacks to more than {max_total_bytes} bytes "
                                   f"(at {info.filename!r}: {declared} bytes declared)", status=413)
            if info.file_size > _allowed(info, max_ratio):
                raise CaptureError(f"zip entry {info.filename!r} declares {info.file_size} bytes from "
                                   f"{info.compress_size} compressed: a compression ratio over the limit of "
                                   f"{max_ratio:g}:1 (a zip bomb?)", status=413)
        manifests = [p for _, p in entries if p.suffix.lower() == ".json"]
        named = [p for p in manifests if p.name.lower() == "manifest.json"]
        if not manifests:
            raise CaptureError("no capture manifest (.json) in the zip")
        if len(named) > 1 or (not named and len(manifests) > 1):
            raise CaptureError("several manifests in the zip: keep one, or name it manifest.json: "
                               + ", ".join(sorted(p.as_posix() for p in (named or manifests))))
        manifest = (named or manifests)[0]
        dest.mkdir(parents=True, exist_ok=True)
        root = dest.resolve()
        written = 0
        for info, p in entries:
            out = dest.joinpath(*p.parts)
            if not out.resolve().is_relative_to(root):       # belt and braces after the name checks
                raise CaptureError(f"zip entry {info.filename!r}: points outside the archive's root", status=400)
            out.parent.mkdir(parents=True, exist_ok=True)
            n = 0
            try:
                with zf.open(info) as r, open(out, "xb") as w:
                    while chunk := r.read(CHUNK):
                        n += len(chunk)
                        written += len(chunk)
                        if n > info.file_size:
                            raise CaptureError(f"zip entry {info.filename!r} unpacks to more than the "
                                               f"{info.file_size} bytes it declares", status=413)
                        if n > _allowed(info, max_ratio):
                            raise CaptureError(f"zip entry {info.filename!r} unpacks to more than {n - len(chunk)} "
                                               f"bytes from {info.compress_size} compressed: a compression ratio "
                                               f"over the limit of {max_ratio:g}:1", status=413)
                        if written > max_total_bytes:
                            raise CaptureError(f"the zip unpacks to more than {max_total_bytes} bytes "
                                               f"(at {info.filename!r})", status=413)
                        w.write(chunk)
            except zipfile.BadZipFile as e:
                raise CaptureError(f"zip entry {info.filename!r} is corrupt ({e})", status=400) from None
            except FileExistsError:
                raise CaptureError(f"zip entry {info.filename!r} appears twice", status=400) from None
            except NotImplementedError as e:
                raise CaptureError(f"zip entry {info.filename!r}: {e}", status=400) from None
    return dest.joinpath(*manifest.parts)


def run_capture(manifest_path: str | Path, progress=None, width: int | None = None,
                root: str | Path | None = None) -> tuple[bytes, bytes, dict]:
    """Process an extracted capture: returns (EXR bytes of the environment map, PNG bytes of its
    preview, stats dict as ``glint capture --json``).

    progress : optional callable(fraction 0..1, message), as the job runner's.
    root : photos must lie inside it; defaults to the manifest's folder (uploads are confined
        to what they contain)."""
    from .pipeline import capture, exr_bytes, preview_png

    manifest_path = Path(manifest_path)
    res = capture(manifest_path, width=width, root=root if root is not None else manifest_path.parent,
                  progress=progress)
    return exr_bytes(res.envmap), preview_png(res.envmap), res.stats
