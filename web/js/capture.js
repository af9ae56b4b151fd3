// "Capture lighting" panel: bracketed fisheye photos → an environment map for the
// scene. The designer picks the photos (and optionally a manifest); the panel builds the capture
// manifest v1 from them, zips everything in the browser, uploads it (POST /v1/captures,
// application/zip), follows the job (GET /v1/captures/{id}), shows the stitched preview
// (GET /v1/captures/{id}/preview) and, on Apply, hands the environment-map asset id to onApply,
// which lights the scene with it (stream message {"type": "environment", "asset_id"}).
//
// Self-contained ES module: mountCapturePanel(container, {api, onApply}). `api` is net.js's
// api(path, opts) (JSON in and out, a Blob for other types); the upload itself goes through
// fetch because it must be sent as application/zip. Nothing runs at import time, so the pure
// helpers (zipStored, crc32, buildManifest, parseExposure) can be imported and tested alone.

// -- a minimal zip writer ------------------------------------------------------------------------
// Why no library: the studio is plain ES modules with no build step and no vendored packages,
// and the photos are JPEGs, which deflate cannot shrink; so the archive stores them (method 0)
// and all a zip needs is a CRC-32 per file, a local header before each file and a central
// directory at the end (PKWARE APPNOTE 4.3). Sizes stay under 4 GiB (no ZIP64): uploads are
// limited far below that.

let CRC_TABLE = null;

export function crc32(bytes) {
  if (!CRC_TABLE) {
    CRC_TABLE = new Uint32Array(256);
    for (let n = 0; n < 256; n++) {
      let c = n;
      for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
      CRC_TABLE[n] = c >>> 0;
    }
  }
  let c = 0xffffffff;
  for (let i = 0; i < bytes.length; i++) c = CRC_TABLE[(c ^ bytes[i]) & 0xff] ^ (c >>> 8);
  return (c ^ 0xffffffff) >>> 0;
}

// entries: [{name: "manifest.json", data: Uint8Array}] → Uint8Array of a stored zip archive.
export function zipStored(entries) {
  const enc = new TextEncoder();
  const seen = new Set();
  const parts = [], central = [];
  let offset = 0;
  // DOS time and date of "now" (the zip's only clock); 1980-01-01 if the clock is unset
  const d = new Date();
  const dosTime = (d.getHours() << 11) | (d.getMinutes() << 5) | (d.getSeconds() >> 1);
  const dosDate = (Math.max(d.getFullYear() - 1980, 0) << 9) | ((d.getMonth() + 1) << 5) | d.getDate();
  for (const { name, data } of entries) {
    if (!name || name.startsWith("/") || name.includes("\\") || name.split("/").includes("..")) {
      throw new Error(`bad file name in the capture: ${name}`);
    }
    if (seen.has(name.toLowerCase())) throw new Error(`two files are named ${name}`);
    seen.add(name.toLowerCase());
    const nameBytes = enc.encode(name);
    const crc = crc32(data);
    const local = new DataView(new ArrayBuffer(30));
    local.setUint32(0, 0x04034b50, true);      // local file header signature
    local.setUint16(4, 20, true);              // version needed: 2.0
    local.setUint16(6, 0x0800, true);          // flags: names are UTF-8
    local.setUint16(8, 0, true);               // method: stored
    local.setUint16(10, dosTime, true);
    local.setUint16(12, dosDate, true);
    local.setUint32(14, crc, true);
    local.setUint32(18, data.length, true);    // compressed size
    local.setUint32(22, data.length, true);    // uncompressed size
    local.setUint16(26, nameBytes.length, true);
    local.setUint16(28, 0, true);              // extra field length
    const cen = new DataView(new ArrayBuffer(46));
    cen.setUint32(0, 0x02014b50, true);        // central directory header signature
    cen.setUint16(4, (3 << 8) | 20, true);     // made by: Unix, 2.0 (so the mode below is read)
    cen.setUint16(6, 20, true);
    cen.setUint16(8, 0x0800, true);
    cen.setUint16(10, 0, true);
    cen.setUint16(12, dosTime, true);
    cen.setUint16(14, dosDate, true);
    cen.setUint32(16, crc, true);
    cen.setUint32(20, data.length, true);
    cen.setUint32(24, data.length, true);
    cen.setUint16(28, nameBytes.length, true);
    cen.setUint16(30, 0, true);                // extra
    cen.setUint16(32, 0, true);                // comment
    cen.setUint16(34, 0, true);                // disk
    cen.setUint16(36, 0, true);                // internal attributes
    cen.setUint32(38, (0o100644 << 16) >>> 0, true);   // external: regular file, rw-r--r--
    cen.setUint32(42, offset, true);           // where the local header is
    parts.push(new Uint8Array(local.buffer), nameBytes, data);
    central.push(new Uint8Array(cen.buffer), nameBytes);
    offset += 30 + nameBytes.length + data.length;
    if (offset > 0xffffffff) throw new Error("the capture is over 4 GiB");
  }
  const cdSize = central.reduce((n, a) => n + a.length, 0);
  const end = new DataView(new ArrayBuffer(22));
  end.setUint32(0, 0x06054b50, true);          // end of central directory
  end.setUint16(8, entries.length, true);
  end.setUint16(10, entries.length, true);
  end.setUint32(12, cdSize, true);
  end.setUint32(16, offset, true);
  const out = new Uint8Array(offset + cdSize + 22);
  let p = 0;
  for (const a of [...parts, ...central, new Uint8Array(end.buffer)]) { out.set(a, p); p += a.length; }
  return out;
}

// -- the manifest --------------------------------------------------------------------------------

// "1/250", "0.004", "4ms" → seconds; "" → null (the server reads the photo's EXIF).
export function parseExposure(text) {
  const t = String(text ?? "").trim().toLowerCase();
  if (!t) return null;
  let v;
  const frac = t.match(/^(\d+(?:\.\d+)?)\s*\/\s*(\d+(?:\.\d+)?)\s*s?$/);
  if (frac) v = parseFloat(frac[1]) / parseFloat(frac[2]);
  else if (/^\d+(\.\d+)?\s*ms$/.test(t)) v = parseFloat(t) / 1000;
  else if (/^\d+(\.\d+)?(e-?\d+)?\s*s?$/.test(t)) v = parseFloat(t);
  if (!(v > 0) || !isFinite(v)) throw new Error(`exposure "${text}": use seconds, e.g. 1/250 or 0.004`);
  return v;
}

// Which shot a photo belongs to when the designer has not said: names with back/rear/180 go to
// the back shot, front/0 to the front; otherwise the first half (by name) is the front.
export function guessShots(names) {
  const sorted = [...names].sort((a, b) => a.localeCompare(b, undefined, { numeric: true }));
  const out = {};
  sorted.forEach((n, i) => {
    if (/back|rear|180/i.test(n)) out[n] = 180;
    else if (/front/i.test(n)) out[n] = 0;
    else out[n] = i < sorted.length / 2 ? 0 : 180;
  });
  return out;
}

// photos: [{name, yaw_deg, exposure_s (number|null)}] → capture manifest version 1.
export function buildManifest(photos, { projection = "equidistant", fov_deg = 190 } = {}) {
  const shots = new Map();
  for (const p of photos) {
    if (!shots.has(p.yaw_deg)) shots.set(p.yaw_deg, []);
    const img = { file: p.name };
    if (p.exposure_s != null) img.exposure_s = p.exposure_s;
    shots.get(p.yaw_deg).push(img);
  }
  for (const [yaw, imgs] of shots) {
    if (imgs.length < 2) throw new Error(`the shot at ${yaw}° has ${imgs.length} photo: bracket at least 2 exposures`);
  }
  return {
    version: 1, projection, fov_deg: Number(fov_deg),
    shots: [...shots.entries()].sort((a, b) => a[0] - b[0]).map(([yaw_deg, images]) => ({ yaw_deg, images })),
  };
}

// -- the panel -----------------------------------------------------------------------------------

const el = (tag, props = {}, ...kids) => {
  const e = Object.assign(document.createElement(tag), props);
  for (const k of kids) e.append(k);
  return e;
};

export function mountCapturePanel(container, { api, onApply, fetchImpl } = {}) {
  const doFetch = fetchImpl || ((...a) => fetch(...a));
  const files = el("input", { type: "file", multiple: true, accept: "image/jpeg,.jpg,.jpeg,.json" });
  const projection = el("select", {}, new Option("equidistant (r = f·θ)", "equidistant"),
    new Option("equisolid (r = 2f·sin θ/2)", "equisolid"));
  const fov = el("input", { type: "number", min: 60, max: 360, step: 1, value: 190, title: "lens field of view, degrees" });
  const table = el("table", { className: "capture-files" });
  const note = el("div", { className: "readout" });
  const upload = el("button", { className: "primary", textContent: "Upload and stitch", disabled: true });
  const bar = el("progress", { max: 1, value: 0, className: "hidden" });
  const status = el("div", { className: "readout" });
  const preview = el("img", { className: "hidden", alt: "stitched environment map" });
  preview.style.width = "100%";
  const apply = el("button", { textContent: "Apply to the scene", disabled: true });
  container.append(el("section", { className: "capture-panel" },
    el("h2", { textContent: "Capture lighting" }),
    el("label", {}, "Photos (and manifest.json)", files),
    el("label", {}, "Projection", projection),
    el("label", {}, "Field of view (°)", fov),
    note, table,
    el("div", { className: "row" }, upload, apply),
    bar, status, preview));

  let manifestFile = null, photos = [], assetId = null, previewUrl = null;
  const say = (t) => { status.textContent = t; };

  function renderTable() {
    table.innerHTML = "";
    if (manifestFile) {
      note.textContent = `${manifestFile.name} describes the capture; the fields below are not used`;
    } else {
      note.textContent = photos.length ? "shot and exposure per photo (exposure blank: read from the photo's EXIF)" : "";
    }
    if (!photos.length) return;
    table.append(el("tr", {}, el("th", { textContent: "photo" }), el("th", { textContent: "shot" }),
      el("th", { textContent: "exposure (s)" })));
    for (const p of photos) {
      const shot = el("select", { disabled: !!manifestFile }, new Option("front (0°)", "0"), new Option("back (180°)", "180"));
      shot.value = String(p.yaw_deg);
      shot.onchange = () => { p.yaw_deg = Number(shot.value); };
      const ex = el("input", { value: p.exposure_text, placeholder: "EXIF", size: 7, disabled: !!manifestFile });
      ex.oninput = () => { p.exposure_text = ex.value; };
      table.append(el("tr", {}, el("td", { textContent: p.file.name }), el("td", {}, shot), el("td", {}, ex)));
    }
  }

  files.onchange = () => {
    const chosen = [...files.files];
    manifestFile = chosen.find((f) => f.name.toLowerCase().endsWith(".json")) || null;
    const images = chosen.filter((f) => !f.name.toLowerCase().endsWith(".json"));
    const shots = guessShots(images.map((f) => f.name));
    photos = images.sort((a, b) => a.name.localeCompare(b.name, undefined, { numeric: true }))
      .map((file) => ({ file, yaw_deg: shots[file.name], exposure_text: "" }));
    upload.disabled = photos.length < 2;
    renderTable();
  };

  async function zipCapture() {
    const entries = [];
    let manifest;
    if (manifestFile) {
      manifest = JSON.parse(await manifestFile.text());
    } else {
      manifest = buildManifest(photos.map((p) => ({ name: p.file.name, yaw_deg: p.yaw_deg,
        exposure_s: parseExposure(p.exposure_text) })), { projection: projection.value, fov_deg: fov.value });
    }
    entries.push({ name: "manifest.json", data: new TextEncoder().encode(JSON.stringify(manifest, null, 1)) });
    for (const p of photos) entries.push({ name: p.file.name, data: new Uint8Array(await p.file.arrayBuffer()) });
    return new Blob([zipStored(entries)], { type: "application/zip" });
  }

  upload.onclick = async () => {
    upload.disabled = apply.disabled = true;
    assetId = null;
    try {
      say("packing the photos…");
      const body = await zipCapture();
      say(`uploading ${(body.size / 1e6).toFixed(1)} MB…`);
      const r = await doFetch("/v1/captures", { method: "POST", headers: { "Content-Type": "application/zip" }, body });
      const job = await r.json().catch(() => ({}));
      if (!r.ok) throw new Error(job.detail ? (typeof job.detail === "string" ? job.detail : JSON.stringify(job.detail)) : `${r.status} ${r.statusText}`);
      bar.classList.remove("hidden");
      for (;;) {
        const s = await api(`/v1/captures/${job.id}`);
        bar.value = s.progress || 0;
        say(`${s.status}: ${Math.round(100 * (s.progress || 0))}% ${s.message || ""}`);
        if (s.status === "done") { assetId = s.asset_id; showStats(s.stats); break; }
        if (s.status === "failed") throw new Error(s.message || "the capture failed");
        await new Promise((res) => setTimeout(res, 700));
      }
      const png = await api(`/v1/captures/${job.id}/preview`);
      if (previewUrl) URL.revokeObjectURL(previewUrl);
      previewUrl = URL.createObjectURL(png);
      preview.src = previewUrl;
      preview.classList.remove("hidden");
      apply.disabled = !assetId;
    } catch (e) {
      say(`capture: ${e.message}`);
    } finally {
      bar.classList.add("hidden");
      upload.disabled = photos.length < 2;
    }
  };

  function showStats(st) {
    if (!st) return;
    const parts = [`${st.width}×${st.height}`, `${st.dynamic_range_stops} stops`];
    if (st.frame_pixels_removed) parts.push(`lens frame removed: ${(100 * st.frame_fraction_of_circle).toFixed(1)}% of each photo`);
    if (st.clipped_fraction_of_sphere > 0) parts.push("some lights clipped in every bracket: add a shorter exposure");
    for (const n of st.exposure_notes || []) parts.push(n);
    say(`done: ${parts.join(" · ")}`);
  }

  apply.onclick = () => { if (assetId && onApply) onApply(assetId); };

  return {
    // for tests and the host page
    get assetId() { return assetId; },
    zipCapture,
  };
}
