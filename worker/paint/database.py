"""The paint database: about thirty measured paints and coatings, as a published reflectance model.

cacad-cosine-lobes §3.2 fits its basis exponents to "about thirty different paints [that]
express the range of BRDFs that can be designed". Glint's database (``data/paints.json``) holds
30 real paints and glossy coatings of the MERL BRDF database (Matusik, Pfister, Brand, McMillan,
"A data-driven reflectance model", SIGGRAPH 2003: painted spheres measured with a camera
gonioreflectometer), each as the Lafortune model fitted to that measurement by Ngan, Durand and
Matusik, "Experimental analysis of BRDF models" (EGSR 2005), whose fitted parameters were
published with the paper. See PROVENANCE in worker/paint/README section of the repository
README for how the values were transcribed and normalised.

The Lafortune model as fitted (one lobe, parameters per entry):
    f(u, v) = ρd/π + ρs · (n+2)/(2π) · max(0, sgn(Cxy)(ux vx + uy vy) + (Cz/|Cxy|) uz vz)^n
u = wi, v = wo in the local frame. ρd, ρs are RGB; Cxy, Cz, n are shared by the channels. For
Cz = −Cxy the lobe is exactly Glint's normalised cosine lobe (n+2)/(2π) (r·v)^n around the mirror
direction; Cz < |Cxy| tilts it towards grazing (off-specular peaks). This normalisation is the
one J.-H. Lee's pbrt plug-in for these fits uses (it reproduces the plug-in's converted values).

The published C vectors are unit vectors rounded to three significant digits. For a sharp lobe
that is too coarse: at normal incidence the lobe is scaled by (Cz/|Cxy|)^n, so −0.578 against
0.577 (equal within the rounding) would scale a lobe of n = 1520 by 0.07. Where |Cxy| and Cz
agree within one unit of the last printed digit (ROUNDING) they are taken as equal (k = 1, the
mirror lobe); otherwise the published ratio is used as it is (then a sharp lobe is strong only
towards grazing, the Fresnel rise these fits put into k).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from .geometry import ASPECULAR_DEG, flop_index, measure

ROUNDING = 0.001

DATA = Path(__file__).parent / "data"
PAINTS_PATH = DATA / "paints.json"


@dataclass(frozen=True)
class Lafortune:
    """One-lobe Lafortune BRDF in the normalised form above (Ngan et al. 2005 fits)."""
    rho_d: tuple[float, float, float]
    rho_s: tuple[float, float, float]
    cxy: float
    cz: float
    n: float

    def evaluate(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """f (…, 3) float64 in 1/sr for local unit directions wi, wo (…, 3); 0 below the horizon."""
        wi = np.asarray(wi, np.float64); wo = np.asarray(wo, np.float64)
        k = 1.0 if abs(abs(self.cxy) - abs(self.cz)) <= ROUNDING + 1e-12 else self.cz / abs(self.cxy)
        s = np.sign(self.cxy) * (wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1]) + k * wi[..., 2] * wo[..., 2]
        lobe = (self.n + 2.0) / (2.0 * np.pi) * np.maximum(s, 0.0) ** self.n
        f = np.asarray(self.rho_d) / np.pi + lobe[..., None] * np.asarray(self.rho_s)
        ok = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        return np.where(ok[..., None], f, 0.0)


def model_of(entry: dict) -> Lafortune:
    src = entry["source"]
    if src["model"] != "lafortune":
        raise ValueError(f"{entry['name']}: unknown source model {src['model']!r}")
    return Lafortune(tuple(src["rho_d"]), tuple(src["rho_s"]), src["Cxy"], src["Cz"], src["n"])


def build_entry(entry: dict) -> dict:
    """Fill an entry's measurements (gloss, aspecular at ASPECULAR_DEG) and flop index from its
    source model. Deterministic: the stored values are this function's output."""
    m = measure(model_of(entry), ASPECULAR_DEG)
    m["gloss"] = round(m["gloss"], 4)
    m["aspecular"] = {k: [round(x, 6) for x in v] for k, v in m["aspecular"].items()}
    out = dict(entry)
    out["measurements"] = m
    out["flop_index"] = round(flop_index(m), 3)
    return out


@lru_cache(maxsize=1)
def load_paints(path: str | None = None) -> tuple[dict, ...]:
    """The database entries: name, category, source (model parameters), measurements, flop_index."""
    data = json.loads(Path(path or PAINTS_PATH).read_text())
    return tuple(data["paints"])


def models(paints=None) -> list[Lafortune]:
    return [model_of(p) for p in (paints or load_paints())]
