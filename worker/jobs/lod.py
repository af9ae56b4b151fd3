"""The level-of-detail policy of a session's frames: full quality or the drag level of detail,
one sample or anti-aliased, half or a quarter of the resolution while dragging, from the
measured cost of recent frames against the session's share of its worker.

``LevelOfDetail`` holds one session's frame-cost history; ``busy_sessions`` counts the
sessions of this worker process that moved something lately (they share its cores).
"""
from __future__ import annotations

import statistics
import threading
import time
from collections import deque

FRAME_BUDGET_MS = 33.0     # a frame while the user drags: 30 fps
# anti-aliasing samples per pixel of a still frame, taken at the pixels next to a silhouette,
# occlusion or crease and where a highlight curves faster than the pixels (renderers/cuts/edges.py):
# elsewhere more samples change nothing. 16, not 4: chosen on the recovery benchmark's bunny and
# sofa2 against 512-spp Mitsuba means (a reference pixel is the mean over its area), where the
# sofa2's 2-3 pixel piping was 7.3% off at 4 and 5.6% at 16 (GGX α 0.1, sunset); held out, the 23K
# dragon under stinson-beach's sun 10.8% → 4.4% (BENCHMARKS.md). A still is drawn once per
# settle and gives way to the next message: 640×480 costs 37 / 99 / 243 ms on the oak chair, the
# couch and the dragon (28 / 48 / 123 at 4), and no more memory (only edge pixels take samples)
STILL_SAMPLES = 16
STILL_ANTIALIAS = "edges"
REPROBE_S = 2.0            # while at the drag level of detail, try a full frame this often
DRAG_SCALES = (2, 4)        # drag level of detail: half the resolution, a quarter under load
ACTIVE_S = 1.0              # a session that moved something this recently shares the worker
_active: dict[int, float] = {}          # id(runtime) -> time.monotonic() of its last move (this process)
_active_lock = threading.Lock()


def mark_busy(key: int) -> None:
    """Session ``key`` (id of its runtime) moved a camera, light or object just now."""
    with _active_lock:
        _active[key] = time.monotonic()


def busy_sessions(now: float) -> int:
    """Sessions of this worker process that moved a camera, light or object in the last
    ACTIVE_S (at least 1): they share its core."""
    with _active_lock:
        for k in [k for k, t in _active.items() if now - t > ACTIVE_S]:
            del _active[k]
        return max(1, len(_active))


def _reprobe(est: float, budget: float) -> float:
    """Seconds between tries of a level that cost ``est`` ms against a ``budget``: REPROBE_S,
    longer the further over budget it was (a full frame at 12× a loaded worker's share is tried
    every 24 s, not every 2 s: each try costs the other sessions their frames)."""
    return REPROBE_S * max(1.0, est / max(budget, 1e-9))


def _estimate(hist) -> float:
    # the latest measurement can lower the estimate at once (a probe on a quieter machine),
    # one slow frame among fast ones cannot raise it
    return min(statistics.median(hist), hist[-1])


class LevelOfDetail:
    """One session's frame-cost history and the level of detail it gives the next frame.

    full_ms : ms of full one-sample frames by what changed since the frame before ("view":
    the camera, "light": the lighting, "other"); quick_ms : the same of quick frames (full
    resolution, the drag level's cuts); drag_ms : ms of drag frames by scale;
    last : (camera, rotation, intensity, dragging, samples) of the last frame."""

    def __init__(self, frame_budget_ms: float = FRAME_BUDGET_MS):
        self.frame_budget_ms = frame_budget_ms
        self.full_ms = {k: deque(maxlen=3) for k in ("view", "light", "other")}
        self.quick_ms = {k: deque(maxlen=3) for k in ("view", "light", "other")}
        self.last = None
        self.last_full = 0.0                   # time.monotonic() of the last full frame
        self.last_quick = 0.0                  # … and of the last quick frame
        self.drag_ms = {k: deque(maxlen=3) for k in DRAG_SCALES}
        self.last_half = 0.0                   # time.monotonic() of the last half-resolution drag frame
        self.drag_scale = DRAG_SCALES[0]

    def change(self, st) -> str:
        """What changed since the last frame: "view" (the camera), "light", or "other"."""
        last = self.last
        if last is None or last[0] != st.camera:
            return "view"
        if (last[1], last[2]) != (st.rotation_deg, st.intensity):
            return "light"
        return "other"

    def choose(self, st, dragging: bool) -> tuple[str, int]:
        """(lod, samples) of the next frame. Outside a drag (the client did not flag its last
        view or light message ``drag``) frames are full quality, and anti-aliased with
        STILL_SAMPLES per pixel once the view has settled: the camera is where the last frame
        had it, or that frame was drawn during a drag (its end); a camera moving without drag
        flags gets one sample per frame (``needs_still`` asks for the settled one after).
        While the user drags, frames are full quality (one sample) whenever the measured cost of
        recent full frames of the same kind of change (camera, light, other) fits the frame
        budget; else quick frames (full resolution on the drag level's cuts and clusters: ~1%
        from full quality, a fitted srbf's frame at about half the cost) when theirs fits; else
        the drag level of detail (half resolution), with each better level tried again every
        REPROBE_S (the machine's load changes).

        The budget is this session's share of its worker: FRAME_BUDGET_MS divided by the
        sessions of this process that moved a camera, light or object in the last second.
        When even the drag level's half-resolution frames do not fit it, they are drawn at a
        quarter of the resolution (``drag_scale`` 4), tried at half again every REPROBE_S: under
        load every designer keeps a fluid, coarser image rather than a few sharp frames."""
        change = self.change(st)
        self.drag_scale = DRAG_SCALES[0]
        if not dragging:
            settled = change != "view" or self.last is None or self.last[3]
            return "full", STILL_SAMPLES if settled else 1
        hist = self.full_ms[change] or self.full_ms["view"]
        if not hist:
            return "full", 1                                     # no measurement yet: measure one
        now = time.monotonic()
        budget = self.frame_budget_ms / busy_sessions(now)
        est = _estimate(hist)
        if est <= budget or now - self.last_full >= _reprobe(est, budget):
            return "full", 1
        quick = self.quick_ms[change] or self.quick_ms["view"]
        if len(quick) < 2:
            # measure (again): the first quick frame of a session (its opening frame, or an
            # edit's answer) also built its view and the coarse cuts, several times the cost
            return "quick", 1
        est = _estimate(quick)
        if est <= budget or now - self.last_quick >= _reprobe(est, budget):
            return "quick", 1
        half = self.drag_ms[DRAG_SCALES[0]]
        if half and _estimate(half) > budget and now - self.last_half < _reprobe(_estimate(half), budget):
            self.drag_scale = DRAG_SCALES[1]
        return "drag", 1

    def follows_moving_frame(self, st) -> bool:
        """The last frame showed this camera, moving (one sample, outside a drag): the next one
        is its anti-aliased follow-up, not put off again."""
        last = self.last
        return last is not None and last[0] == st.camera and not last[3] and last[4] < STILL_SAMPLES

    def record(self, st, dragging: bool, lod: str, samples: int, change: str, ms: float) -> None:
        """A frame was drawn at (lod, samples) in ``ms`` (render and encode) after ``change``."""
        if lod == "drag":
            self.drag_ms[self.drag_scale].append(ms)
            if self.drag_scale == DRAG_SCALES[0]:
                self.last_half = time.monotonic()
        if lod == "full":
            self.last_full = time.monotonic()
            if samples == 1:
                self.full_ms[change].append(ms)
        if lod == "quick":
            self.last_quick = time.monotonic()
            self.quick_ms[change].append(ms)
        # the samples asked for: a renderer without anti-aliasing (gi, paint, movable objects)
        # draws one, and must not be asked again and again for a still frame
        self.last = (st.camera, st.rotation_deg, st.intensity, dragging, samples)

    def needs_still(self, dragging: bool) -> bool:
        """Whether the last frame was a moving one (one sample, or the drag level of detail) and
        the session is not dragging: one more frame is the settled, anti-aliased image."""
        return self.last is not None and not dragging and self.last[4] < STILL_SAMPLES
