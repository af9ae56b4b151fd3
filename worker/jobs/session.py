"""One interactive design session inside a worker process: the scene's engine, the paint-to-BRDF
fitter of the edited object, and the state the client steers (camera, light, materials, display).

The state is rebuilt exactly from what the server persisted (state + stroke list), so a worker
that dies loses nothing: ``SessionRuntime(payload)`` on a new worker gives the same frames.
"""
from __future__ import annotations

import io
import json
from contextlib import contextmanager
import threading
import time

import numpy as np
from PIL import Image

from ..core.tonemap import tonemap
from ..engine import Engine
from ..fit.brush import Stroke
from ..fit.fitter import FitError, Fitter
from ..scene import Camera, Material, SRBF
from .protocol import client_msg

CURVE_SAMPLES = 91
DRAG_TAU = 16.0     # level of detail while dragging: cuts coarsened to τ = 16 (measured: 0.4% image change on the demo chair)
_coarse_lock = threading.Lock()


def coarse_cuts(cuts):
    """The drag-time cut set of ``cuts`` (cuts.coarsen at DRAG_TAU), built once per cut set
    (about 0.1 s for 21K vertices in C) and kept on it."""
    with _coarse_lock:
        if getattr(cuts, "_coarse", None) is None:
            from ..core.cuts import coarsen
            cuts._coarse = coarsen(cuts, DRAG_TAU)
        return cuts._coarse


def brdf_curve(material, n: int = CURVE_SAMPLES) -> dict:
    """The 1D half-angle distribution to plot: p(θh) averaged over φh for srbf, the curve's
    values for curve, and f(θh) in the plane of incidence at normal viewing otherwise.
    Returns {"theta_deg": [...], "values": [[r, g, b], ...], "quantity": str}."""
    from ..core.brdf import evaluate, srbf_p

    th = np.linspace(0.0, 90.0, n)
    t = np.radians(th)
    if isinstance(material, SRBF):
        ph = np.linspace(0, 2 * np.pi, 48, endpoint=False)
        T, P = np.meshgrid(t, ph, indexing="ij")
        h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
        c = np.asarray(material.centers, np.float64)
        c /= np.linalg.norm(c, axis=1, keepdims=True)
        vals = srbf_p(h, c, material.bandwidth, np.asarray(material.coefficients)).mean(axis=1)
        q = "p(θh), mean over φh"
    else:
        # ωo = normal, ωi at 2θh in the x-z plane, so θh is the half angle
        wo = np.broadcast_to([0.0, 0.0, 1.0], (n, 3))
        wi = np.stack([np.sin(2 * t), np.zeros(n), np.cos(2 * t)], -1)
        vals = evaluate(material, wi, wo)       # zero past θh = 45°, where ωi is below the horizon
        q = "f(ωi, ωo = n), θh = θi / 2"
    return {"theta_deg": th.round(3).tolist(), "values": np.asarray(vals, np.float64).round(6).tolist(), "quantity": q}


class SessionRuntime:
    """scene : LoadedScene, cuts : CutSet, state : the session state the server stores (camera,
    light, materials, edited object, display, fit options, environment presets), strokes :
    [{"stroke": {...}, "camera": {...}, "rotation_deg": r, "intensity": i, "undone": bool}, ...]
    in painting order (server/routes/sessions.py persist)."""

    def __init__(self, scene, cuts, state: dict, strokes: list[dict], env_loader=None):
        self.scene = scene
        self.env_loader = env_loader      # file info -> (H, W, 3) map, for environment presets
        self.environments = state.get("environments") or []
        self.env_index = 0
        self.engine = Engine(scene, cuts)
        spec = scene.spec
        names = [o.name for o in spec.objects]
        self.names = names
        self.object = state.get("object") or names[0]
        if self.object not in names:
            raise FitError(f"no object {self.object!r} in the scene")
        self.camera = Camera.model_validate(state.get("camera") or spec.camera.model_dump())
        self.rotation = float(state.get("rotation_deg", spec.environment.rotation_deg))
        self.intensity = float(state.get("intensity", spec.environment.intensity))
        mats = state.get("materials")
        from pydantic import TypeAdapter
        ta = TypeAdapter(Material)
        self.materials = [ta.validate_python(m) for m in mats] if mats else list(scene.materials)
        base = state.get("base_material")
        self.base = ta.validate_python(base) if base else self.materials[names.index(self.object)]
        self.exposure = float(state.get("exposure", 0.0))
        self.tone = state.get("tone", "neutral")
        self.quality = int(state.get("quality", 85))
        self.constrained = bool(state.get("constrained", True))
        self.unpainted_weight = float(state.get("unpainted_weight", 1.0))
        self.frame_no = 0
        self.fitter: Fitter | None = None
        self.engine.set_materials(self.materials)
        if self.environments:
            self._set_environment(int(state.get("environment_index", 0)))
        self._needs_fit = False
        self._drag = False
        # pay the basis's one-time costs (energy rows, solver import) at open, not on the first stroke
        from ..fit.basis import default_basis
        from ..fit import solve  # noqa: F401
        default_basis().energy_rows()
        coarse_cuts(cuts)                 # the drag-time level of detail
        # replay the persisted strokes (undone ones form the redo stack, most recent last)
        active = [s for s in strokes if not s.get("undone")]
        undone = [s for s in strokes if s.get("undone")]
        for s in active:
            self._add_stroke(s)
        for s in undone:
            self._add_stroke(s)
        for _ in undone:
            self.fitter.undo()
        if strokes:
            self._needs_fit = True
        self.last_fit: dict | None = None
        self._fitted = None       # the material the fitter produced last (identity)
        self._vt = None           # per-vertex transfer of the edited object: (key, ids, T, E)

    # -- state changes ---------------------------------------------------------------------
    @contextmanager
    def _base_shading(self):
        """The engine shades the edited object with the base material (what strokes paint
        over) inside the block, with the current materials after it."""
        mats = list(self.materials)
        mats[self.names.index(self.object)] = self.base
        self.engine.set_materials(mats)
        try:
            yield
        finally:
            self.engine.set_materials(self.materials)

    def _ensure_fitter(self):
        if self.fitter is None:
            with self._base_shading():
                self.fitter = Fitter(self.engine, self.object, fit_scale=0.25)
        return self.fitter

    def _view_index(self, camera: Camera, rot: float, inten: float) -> int:
        fx = self._ensure_fitter()
        for i, v in enumerate(fx.views):
            if v.camera == camera and v.rotation_deg == rot and v.intensity == inten:
                return i
        with self._base_shading():
            return fx.add_view(camera, rot, inten)

    def _add_stroke(self, rec: dict) -> list[str]:
        cam = Camera.model_validate(rec["camera"])
        i = self._view_index(cam, float(rec["rotation_deg"]), float(rec["intensity"]))
        st = Stroke.model_validate({**rec["stroke"], "view": i})
        return self.fitter.add_stroke(st)

    def _set_environment(self, index: int) -> None:
        if not 0 <= index < len(self.environments) or self.env_loader is None:
            raise FitError(f"no environment preset {index} (there are {len(self.environments)})")
        env = self.environments[index]
        self.engine.set_envmap(self.env_loader(env))
        self.rotation = float(env.get("rotation_deg", self.rotation))
        self.env_index = index
        self._vt = None

    def stroke_record(self, stroke: Stroke) -> dict:
        """What the server persists for a stroke: the stroke and the view it was painted in."""
        return {"stroke": stroke.model_dump(), "camera": self.camera.model_dump(),
                "rotation_deg": self.rotation, "intensity": self.intensity}

    def apply(self, msg: dict) -> list[dict]:
        """Apply one client message; returns JSON events for the client."""
        m = client_msg.validate_python(msg)
        ev = []
        t = m.type
        if t == "view":
            upd = {k: getattr(m, k) for k in ("eye", "target", "up", "fov_y_deg") if getattr(m, k) is not None}
            self.camera = Camera.model_validate({**self.camera.model_dump(), **upd})
            self._drag = m.drag
        elif t == "light":
            if m.rotation_deg is not None:
                self.rotation = float(m.rotation_deg)
            if m.intensity is not None:
                self.intensity = float(m.intensity)
            self._drag = m.drag
        elif t == "material":
            name = m.object or self.object
            if name not in self.names:
                raise FitError(f"no object {name!r} in the scene")
            self.materials[self.names.index(name)] = m.material
            self.engine.set_materials(self.materials)
            if name == self.object:
                # strokes painted over the old material do not carry over to a new base
                self.base = m.material
                self.fitter = None
                self._needs_fit = False
            ev.append({"type": "curve", "seq": m.seq, "object": name, "curve": brdf_curve(m.material)})
        elif t == "stroke":
            notes = self._add_stroke(self.stroke_record(m.stroke))
            self._needs_fit = True
            ev.append({"type": "stroke", "seq": m.seq, "strokes": len(self.fitter.history), "notes": notes})
        elif t in ("undo", "redo"):
            if self.fitter is not None and (self.fitter.undo() if t == "undo" else self.fitter.redo()) is not None:
                self._needs_fit = True
            else:
                ev.append({"type": "note", "seq": m.seq, "message": f"nothing to {t}"})
        elif t == "fit":
            if m.constrained is not None:
                self.constrained = m.constrained
            if m.unpainted_weight is not None:
                self.unpainted_weight = m.unpainted_weight
            self._needs_fit = True
        elif t == "environment":
            self._set_environment(m.index)
        elif t == "variant":
            raise FitError("variants are chosen by the server (viewer sessions only)")
        elif t == "display":
            if m.exposure is not None:
                self.exposure = m.exposure
            if m.tone is not None:
                self.tone = m.tone
            if m.quality is not None:
                self.quality = m.quality
        elif t == "save":
            ev += self.fit_if_needed()
            mat = self.materials[self.names.index(self.object)]
            ev.append({"type": "save", "seq": m.seq, "object": self.object, "name": m.name,
                       "material_id": m.material_id, "material": json.loads(mat.model_dump_json())})
        return ev

    def fit_if_needed(self) -> list[dict]:
        if not self._needs_fit:
            return []
        self._needs_fit = False
        fx = self.fitter
        i = self.names.index(self.object)
        if fx is None or len(fx.history) == 0:
            self.materials[i] = self.base
            self.engine.set_materials(self.materials)
            return [{"type": "fit", "object": self.object, "material": json.loads(self.base.model_dump_json()),
                     "curve": brdf_curve(self.base), "stats": {"strokes": 0}}]
        out = fx.fit(constrained=self.constrained, unpainted_weight=self.unpainted_weight)
        self.materials[i] = out.material
        self._fitted = out.material
        self.engine.set_materials(self.materials)
        self._vertex_transfer()
        s = out.solve
        stats = {"strokes": len(fx.history), "pixels": out.pixels, "painted": out.painted,
                 "ms_solve": s.seconds * 1e3, "ms_transfer": out.seconds_transfer * 1e3,
                 "residual_rel": s.residual_rel, "energy_max": s.energy_max,
                 "energy_bound": float(s.energy_bound.min()), "constrained": s.constrained}
        self.last_fit = stats
        return [{"type": "fit", "object": self.object, "material": json.loads(out.material.model_dump_json()),
                 "curve": brdf_curve(out.material), "stats": stats, "notes": out.notes}]

    # -- frames --------------------------------------------------------------------------------
    def _view_key(self):
        return (self.camera.model_dump_json(), self.rotation, self.intensity)

    def _vertex_transfer(self):
        """Per-vertex transfer of the edited object's visible vertices for the current view and
        light (inverse-brdf-modeling eq. 22 with the basis): while only the fitted coefficients
        change (strokes, undo, redo), a frame's shading of that object is one mat-vec."""
        from ..fit.transfer import transfer

        key = self._view_key()
        if self._vt is not None and self._vt[0] == key:
            return self._vt
        eng, fx = self.engine, self.fitter
        mesh = eng.scene.mesh
        vis = eng.view(self.camera).visible
        ids = vis[eng.scene.object_of_vertex[vis] == self.names.index(self.object)]
        wo = np.asarray(self.camera.eye, np.float32) - mesh.vertices[ids]
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        node_l, node_w = eng.node_light(self.rotation, self.intensity)
        verts = np.repeat(ids[:, None], 3, axis=1).astype(np.int32)
        bary = np.zeros((len(ids), 3), np.float32)
        bary[:, 0] = 1.0
        T, E = transfer(mesh.normals[ids].astype(np.float32), wo.astype(np.float32), verts, bary, eng.cuts,
                        node_l, node_w, eng.tree, fx.basis)
        self._vt = (key, ids, T, E)
        return self._vt

    def _override(self):
        """Known radiance of the edited object's vertices, when its material is the current fit
        and the per-vertex transfer matches the view and light."""
        i = self.names.index(self.object)
        if self._fitted is None or self.materials[i] is not self._fitted or self._vt is None \
                or self._vt[0] != self._view_key():
            return None
        _, ids, T, E = self._vt
        c = np.asarray(self._fitted.coefficients, np.float32)
        rad = np.asarray(self._fitted.albedo, np.float32) * E + np.stack([T[k] @ c[:, k] for k in range(3)], axis=1)
        return ids, rad.astype(np.float32)

    def frame(self, ack: int) -> tuple[dict, bytes]:
        t0 = time.perf_counter()
        # while the user drags (DESIGN.md §5: lower quality while dragging): a coarser cut set
        # and half the resolution; the client scales the frame to its canvas
        lod = coarse_cuts(self.engine.cuts) if self._drag else None
        cam = self.camera
        if self._drag and cam.width >= 320:
            cam = cam.model_copy(update={"width": cam.width // 2, "height": cam.height // 2})
        img = self.engine.render(cam, self.rotation, self.intensity,
                                 vertex_override=None if lod is not None else self._override(), cuts=lod)
        rgb = tonemap(img, self.exposure, self.tone)
        t1 = time.perf_counter()
        buf = io.BytesIO()
        # lower quality while the user drags (DESIGN.md §5), full quality when still
        Image.fromarray(rgb).save(buf, format="JPEG", quality=min(self.quality, 60) if self._drag else self.quality)
        self.frame_no += 1
        hdr = {"frame": self.frame_no, "ack": ack, "width": cam.width, "height": cam.height,
               "format": "jpeg", "ms_render": round((t1 - t0) * 1e3, 2), "lod": lod is not None,
               "ms_encode": round((time.perf_counter() - t1) * 1e3, 2)}
        return hdr, buf.getvalue()


def encode_frame(header: dict, image: bytes) -> bytes:
    """Binary WebSocket frame: 4-byte big-endian header length | UTF-8 JSON header | image."""
    h = json.dumps(header, separators=(",", ":")).encode()
    return len(h).to_bytes(4, "big") + h + image


def decode_frame(data: bytes) -> tuple[dict, bytes]:
    n = int.from_bytes(data[:4], "big")
    return json.loads(data[4:4 + n]), data[4 + n:]
