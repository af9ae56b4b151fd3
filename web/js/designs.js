// The designs panel: named designs with versions, as a designer used to Figma or Substance expects.
//  - "Save" stores a new version of the design being edited (the version gets the note typed,
//    if any); with no design yet it makes one with the name typed.
//  - "Save as new design" always makes a new design with the name typed; "New design" starts one
//    (the next save creates it) from the current look.
//  - The version list shows each version's name, date and thumbnail (the frame it was saved from,
//    stored with it by the server); "load" puts a version's material back on the object.
//  - Publish works from any saved design of the scene (ticked in the list; the one edited by
//    default), also after a reload: the designs come from the server, not from this page.
//  - Autosave: edits are stored in the session as they happen (a reload or another tab reopens it);
//    with Autosave on, a design being edited also gets an "autosave" version after AUTOSAVE_MS
//    without edits and when the tab is closed, so closing the tab never loses a look.
import { api } from "./net.js";
import { setUrl } from "./persist.js";

const $ = (id) => document.getElementById(id);
const AUTOSAVE_MS = 30_000;
const when = (iso) => new Date(iso).toLocaleString([], { dateStyle: "short", timeStyle: "short" });

export function mountDesigns({ status, send, session, state, applyMaterial }) {
  let designId = null, version = null, designs = [], dirty = false, timer = null;
  const picked = new Set();                // designs ticked for the publication
  const thumbs = new Map();                // thumbnail URL -> object URL (versions never change)

  async function thumb(url) {
    if (!url) return null;
    if (!thumbs.has(url)) thumbs.set(url, api(url).then((b) => URL.createObjectURL(b)).catch(() => null));
    return thumbs.get(url);
  }

  function info() {
    const d = designs.find((x) => x.id === designId);
    $("design-info").textContent = d
      ? `editing “${d.name}”${version ? ` from v${version}` : ""}${dirty ? " · unsaved changes (kept in the session)" : ""}`
      : `no design yet: Save makes “${$("design-name").value || "design"}”${dirty ? " · edits are kept in the session" : ""}`;
    $("save").textContent = d ? `Save v${(d.version || 0) + 1}` : "Save";
  }

  // the designs of the session's scene, newest first, with the publish ticks
  async function loadDesigns() {
    const s = session();
    if (!s) return;
    const all = await api("/v1/materials");
    designs = all.filter((d) => d.scene_id === s.scene_id || d.id === designId);
    const sel = $("design-select");
    sel.innerHTML = "";
    sel.append(new Option(designs.length ? "open a design…" : "no saved designs for this scene", ""));
    for (const d of designs) sel.append(new Option(`${d.name} · v${d.version}`, d.id));
    sel.value = "";
    const box = $("publish-pick");
    box.innerHTML = "";
    if (designId) picked.add(designId);
    for (const d of designs) {
      const l = document.createElement("label");
      l.className = "pick";
      const c = Object.assign(document.createElement("input"), { type: "checkbox", checked: picked.has(d.id) });
      c.dataset.design = d.id;
      c.onchange = () => (c.checked ? picked.add(d.id) : picked.delete(d.id));
      const img = document.createElement("img");
      img.alt = "";
      thumb(d.thumbnail).then((u) => { if (u) img.src = u; else img.classList.add("hidden"); });
      l.append(c, img, document.createTextNode(`${d.name} (v${d.version})`));
      box.append(l);
    }
    info();
  }

  async function loadVersions() {
    const ul = $("versions");
    ul.innerHTML = "";
    if (!designId) return;
    const vs = await api(`/v1/materials/${designId}/versions`);
    for (const v of vs.reverse()) {
      const li = document.createElement("li");
      li.dataset.version = v.version;
      const img = document.createElement("img");
      img.alt = `v${v.version}`;
      img.width = 64; img.height = 48;
      thumb(v.thumbnail).then((u) => { if (u) img.src = u; });
      const text = document.createElement("span");
      text.className = "vtext";
      const b1 = document.createElement("b");
      b1.textContent = `v${v.version}${v.name ? ` · ${v.name}` : ""}`;
      const small = document.createElement("small");
      small.textContent = `${when(v.created)} · ${v.material.model}`;
      text.append(b1, document.createElement("br"), small);
      const b = document.createElement("button");
      b.textContent = "load";
      b.onclick = () => { version = v.version; applyMaterial(v.material); setUrl({ version: v.version }); dirty = false; info(); };
      li.append(img, text, b);
      ul.append(li);
    }
  }

  // edit design ``id`` (its version ``v``, else the latest); apply: put its material on the object
  // (a new session); a reopened session keeps its own, possibly newer, edits
  async function open(id, v = null, apply = true) {
    const d = await api(`/v1/materials/${id}`);
    designId = d.id;
    version = v || d.version;
    $("design-name").value = d.name;
    if (apply) {
      const m = v && v !== d.version ? (await api(`/v1/materials/${id}/versions/${v}`)).material : d.material;
      applyMaterial(m);
      dirty = false;
    }
    setUrl({ design: d.id, version });
    await loadDesigns();
    await loadVersions();
  }

  function save(asNew) {
    if (!session()) return status("open a scene first");
    const name = $("design-name").value.trim() || "design";
    if (asNew || !designId) {
      const taken = designs.some((d) => d.name === name);
      send("save", { name: asNew && taken ? `${name} (copy)` : name, material_id: null });
    } else {
      send("save", { name: $("version-name").value.trim() || null, material_id: designId });
    }
    clearTimeout(timer);
  }

  function onSaved(ev) {
    designId = ev.material_id;
    version = ev.version;
    dirty = false;
    $("design-name").value = ev.name;
    $("version-name").value = "";
    setUrl({ design: designId, version });
    status(`saved “${ev.name}” version ${ev.version}`);
    loadDesigns().then(loadVersions);
  }

  // something changed the look (a stroke's fit, a slider, the curve, paint): autosave later
  function edited() {
    dirty = true;
    info();
    clearTimeout(timer);
    if ($("autosave").checked && designId) timer = setTimeout(() => dirty && autosave(), AUTOSAVE_MS);
  }
  function autosave() {
    if (!dirty || !designId || !$("autosave").checked) return;
    send("save", { name: "autosave", material_id: designId });
    dirty = false;
  }
  // the tab closes or goes to the background: the stream is still open long enough to send, and
  // the server stores a save that arrives as the stream closes
  window.addEventListener("beforeunload", autosave);
  window.addEventListener("pagehide", autosave);
  document.addEventListener("visibilitychange", () => { if (document.visibilityState === "hidden") autosave(); });

  $("autosave").checked = localStorage.getItem("glint.autosave") !== "off";
  $("autosave").onchange = () => localStorage.setItem("glint.autosave", $("autosave").checked ? "on" : "off");
  $("save").onclick = () => save(false);
  $("save-as").onclick = () => save(true);
  $("new-design").onclick = () => {
    designId = null; version = null;
    $("design-name").value = "untitled design";
    $("versions").innerHTML = "";
    setUrl({ design: null, version: null });
    loadDesigns();
    status("new design: Save stores the current look under the name typed");
  };
  $("design-select").onchange = () => { const id = $("design-select").value; if (id) open(id, null, true); };
  $("design-name").addEventListener("input", info);
  // the designs ticked in the list, else the one being edited (what Publish and Export take)
  function chosen() {
    const ids = designs.filter((d) => picked.has(d.id)).map((d) => d.id);
    if (!ids.length && designId) ids.push(designId);
    return ids;
  }
  $("publish").onclick = async () => {
    const s = session(), st = state();
    if (!s) return status("open a scene first");
    const ids = chosen();
    if (!ids.length) {
      // nothing edited here yet (another browser, a new session): the ticks are where to choose
      if (designs.length) $("publish-details").open = true;
      return status(designs.length ? "tick the designs to publish under “Designs in the publication”" : "save a design first");
    }
    try {
      const name = designs.find((d) => d.id === (designId || ids[0]))?.name || "designs";
      // the lighting the designer sees: the scene's map turned as the Light tool left it (a
      // captured map applied in the session is not an uploaded preset here: the scene's map then)
      const environments = st.environment_index == null ? [{ rotation_deg: st.rotation_deg ?? 0 }] : [];
      const p = await api("/v1/publications", { method: "POST", body: { name, scene_id: s.scene_id, object: st.object,
        variants: ids.map((id) => ({ material_id: id })), environments,
        bundle: { azimuths: +$("publish-frames").value } } });
      const a = $("publish-link");
      a.href = p.viewer; a.textContent = `open the viewer (${p.variants.length} variant${p.variants.length > 1 ? "s" : ""})`;
      a.classList.remove("hidden");
      status(`published ${p.id}`);
    } catch (err) { status(`publish failed: ${err.message}`); }
  };

  return {
    // a session was opened or reopened; design: the one it edits (from the URL), or null
    async start(design = null, v = null, apply = false) {
      designId = null; version = null; dirty = false;
      $("versions").innerHTML = "";
      $("publish-link").classList.add("hidden");
      if (design) {
        try { return await open(design, v, apply); } catch (err) { status(`design ${design}: ${err.message}`); setUrl({ design: null, version: null }); }
      }
      await loadDesigns();
    },
    onSaved, edited, open, chosen,
    current: () => designId,
  };
}
