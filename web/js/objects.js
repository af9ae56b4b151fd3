// The scene's objects in the studio: listed, picked by clicking them in the image (the worker
// answers a `pick` message from the last frame's object ids with a `picked` event), and the
// edited one changed by an `object` message. The material panel, the curve editor and the brush
// act on the edited object; each object keeps its own strokes and undo history (the session's
// state), so picking one back brings its strokes back.

export function mountObjects(select, { send, status }) {
  let current = null;
  select.addEventListener("change", () => choose(select.value));
  function choose(name) {
    if (!name || name === current) return;
    status(`editing ${name}…`);
    send("object", { object: name });
  }
  return {
    // the scene's objects and the edited one (a session's state)
    show(names, edited) {
      if ([...select.options].map((o) => o.value).join("\n") !== names.join("\n")) {
        select.innerHTML = "";
        for (const n of names) select.append(new Option(n, n));
      }
      select.closest("label")?.classList.toggle("hidden", names.length < 2);
      this.selected(edited);
    },
    selected(name) { current = name; select.value = name; select.dataset.edited = name; },
    picked(ev) {
      if (!ev.object) return status("nothing there to pick: click an object");
      if (ev.object === current) return status(`${ev.object} is the edited object`);
      choose(ev.object);
    },
    get current() { return current; },
  };
}

// a pointer press and release that did not move (and was short): a click, not a drag
export function isClick(down, up) {
  return down && Math.hypot(up.clientX - down.x, up.clientY - down.y) < 4 && performance.now() - down.t < 500;
}

// where a pointer event lies in the image, as fractions of its width and height
export function imageFraction(canvas, e) {
  const r = canvas.getBoundingClientRect();
  const c = (x) => Math.min(1, Math.max(0, x));
  return { u: c((e.clientX - r.left) / r.width), v: c((e.clientY - r.top) / r.height) };
}
