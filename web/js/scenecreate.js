// Creating a scene from the studio: meshes and an HDRI uploaded, the renderer chosen (direct
// light with visibility cuts, global illumination, car paint), the movable objects marked (the
// cut renderer precomputes a visibility field for each), then the precomputation started and
// its progress followed until the scene opens.

const RENDERER_FRAME = {
  // GI precomputes light transport per pixel of one fixed view: a small frame keeps it within a
  // minute or so, and its tensors denoised once (Open Image Denoise) keep 64 paths a pixel from
  // showing as grain. 128×96 without denoising looked broken when the canvas scaled it up
  // (the bunny: 1.9 s with denoising at 128×96, 6.9 s at 256×192; the sofa at 320×240 30-60 s).
  gi: { width: 256, height: 192, options: { spp: 64, denoise: true } },
};

export function mountSceneCreate(root, { api, status, waitPrecompute, onCreated }) {
  const $ = (sel) => root.querySelector(sel);
  const meshes = $("#mesh-file"), list = $("#mesh-list"), kind = $("#scene-renderer");
  const showList = () => {
    list.innerHTML = "";
    const movableOk = kind.value === "cuts";
    [...meshes.files].forEach((f, i) => {
      const li = document.createElement("li");
      const cb = Object.assign(document.createElement("input"), { type: "checkbox", disabled: !movableOk });
      cb.dataset.index = String(i);
      cb.setAttribute("aria-label", `${f.name} is movable`);
      const label = document.createElement("label");
      label.title = movableOk ? "a movable object gets a precomputed visibility field: it can be dragged on the floor"
        : "only the direct-light renderer moves objects";
      label.append(cb, ` ${f.name} movable`);
      li.append(label);
      list.append(li);
    });
  };
  meshes.addEventListener("change", showList);
  kind.addEventListener("change", showList);

  $("#upload").addEventListener("click", async () => {
    const files = [...meshes.files], env = $("#env-file").files[0];
    if (!files.length || !env) return status("choose one or more meshes and an HDRI first");
    const movable = new Set([...list.querySelectorAll("input:checked")].map((c) => +c.dataset.index));
    try {
      const objects = [];
      let lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
      for (const [i, f] of files.entries()) {
        status(`uploading ${f.name} (${i + 1}/${files.length})…`);
        const m = await api(`/v1/assets/meshes?filename=${encodeURIComponent(f.name)}`, { method: "POST", raw: f });
        const [a, b] = m.meta.bounds;
        lo = lo.map((x, k) => Math.min(x, a[k])); hi = hi.map((x, k) => Math.max(x, b[k]));
        let name = f.name.replace(/\.[^.]+$/, "");
        while (objects.some((o) => o.name === name)) name += "'";
        objects.push({ name, mesh: m.id, material: { model: "lambert", albedo: [0.5, 0.5, 0.5] },
                       ...(movable.has(i) && kind.value === "cuts" ? { movable: true } : {}) });
      }
      status(`uploading ${env.name}…`);
      const e = await api(`/v1/assets/envmaps?filename=${encodeURIComponent(env.name)}`, { method: "POST", raw: env });
      const c = lo.map((x, i) => (x + hi[i]) / 2), r = Math.hypot(...hi.map((x, i) => x - lo[i])) / 2;
      const frame = RENDERER_FRAME[kind.value] || { width: 640, height: 480 };
      const scene = { version: 1, renderer: kind.value, environment: { map: e.id },
        camera: { eye: [c[0], c[1] + 0.4 * r, c[2] + 2.8 * r], target: c, up: [0, 1, 0], fov_y_deg: 40,
                  width: frame.width, height: frame.height },
        // the worker exposes the first frame: the median object pixel middle grey
        objects, exposure: "auto", ...(kind.value === "cuts" ? { ground: { shadow: true } } : {}),
        ...(frame.options ? { [kind.value]: frame.options } : {}) };
      const name = $("#scene-name").value || files[0].name;
      const s = await api(`/v1/scenes?name=${encodeURIComponent(name)}`, { method: "POST", body: scene });
      await api(`/v1/scenes/${s.id}/precompute`, { method: "POST" });
      await waitPrecompute(s.id);
      await onCreated(s.id);
    } catch (err) { status(`creating the scene failed: ${err.message}`); }
  });
}
