// Standard exports from the studio: the scene with the designs saved in this page as variants,
// as glTF (.glb, KHR_materials_variants), MaterialX (.mtlx, OpenPBR) or a Mitsuba 3 folder (zip),
// through POST /v1/exports. The approximation errors the server reports are shown beside the link.

const FORMATS = [["gltf", "glTF 2.0 (.glb)"], ["mtlx", "MaterialX OpenPBR (.mtlx)"], ["mitsuba", "Mitsuba 3 scene (.zip)"]];

function pct(x) { return `${(100 * x).toFixed(1)}%`; }

// The report's one line: each material's relative BRDF RMSE, and the render check's worst.
export function describeReport(rep) {
  const mats = rep.materials.map((m) => `${m.label}: ${pct(m.rel_rmse)}`).join(" · ");
  const render = rep.render ? ` · render ${pct(Math.max(...rep.render.map((r) => r.rel_rmse)))}` : "";
  return `BRDF error ${mats}${render}`;
}

// context() -> { sceneId, object, designs: [material ids] } of the page now.
export function mountExportPanel(root, context, status = () => {}) {
  root.innerHTML = "";
  const row = document.createElement("div");
  row.className = "row";
  const sel = document.createElement("select");
  sel.id = "export-format";
  sel.title = "export format";
  for (const [v, label] of FORMATS) sel.append(new Option(label, v));
  const check = document.createElement("label");
  check.title = "also render the exported materials with Glint and compare (slower)";
  const box = document.createElement("input");
  box.type = "checkbox";
  box.id = "export-render-check";
  check.append(box, " render check");
  const btn = document.createElement("button");
  btn.id = "export";
  btn.textContent = "Export";
  row.append(sel, check, btn);
  const link = document.createElement("a");
  link.id = "export-link";
  link.className = "hidden";
  const info = document.createElement("div");
  info.id = "export-report";
  info.className = "readout";
  root.append(row, link, info);

  btn.onclick = async () => {
    const { sceneId, object, designs } = context();
    if (!sceneId) return status("open a scene first");
    const format = sel.value;
    // a Mitsuba scene holds one material per object: the scene as it is, without variants
    const variants = format === "mitsuba" ? [] : designs.map((id) => ({ material_id: id }));
    btn.disabled = true;
    info.textContent = "";
    status(`exporting (${format}): fitting ${variants.length + 1} material(s)…`);
    try {
      const r = await fetch("/v1/exports", { method: "POST", headers: { "Content-Type": "application/json" },
        body: JSON.stringify({ scene_id: sceneId, format, object, variants, render_check: box.checked }) });
      if (!r.ok) {
        const body = await r.json().catch(() => ({}));
        throw new Error(typeof body.detail === "string" ? body.detail : `${r.status} ${r.statusText}`);
      }
      const blob = await r.blob();
      const name = /filename="([^"]+)"/.exec(r.headers.get("content-disposition") || "")?.[1] || `scene.${format}`;
      if (link.href) URL.revokeObjectURL(link.href);
      link.href = URL.createObjectURL(blob);
      link.download = name;
      link.textContent = `download ${name} (${(blob.size / 1024).toFixed(0)} KiB)`;
      link.classList.remove("hidden");
      const rep = JSON.parse(r.headers.get("x-glint-export-report") || "null");
      if (rep) info.textContent = describeReport(rep);
      status(`exported ${name}`);
    } catch (err) {
      status(`export failed: ${err.message}`);
    } finally {
      btn.disabled = false;
    }
  };
}
