"""web/js/paint.js: its BRDF (lobe visualiser, swatches) and its export agree with the worker's."""
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from worker.core.brdf import evaluate
from worker.paint.geometry import export_measurements, measure
from worker.scene import Lobes

JS = Path(__file__).resolve().parents[2] / "web" / "js" / "paint.js"


@pytest.mark.skipif(shutil.which("node") is None, reason="node not installed")
def test_js_brdf_and_export_match_python(tmp_path):
    mat = Lobes(exponents=[1.0, 12.0, 900.0], gloss=[0.0, 0.01, 0.04],
                directional_diffuse=[(0.2, 0.1, 0.05), (0.3, 0.3, 0.2), (0.0, 0.0, 0.0)], albedo=(0.05, 0.04, 0.03))
    rng = np.random.default_rng(0)
    wi = rng.normal(size=(40, 3)); wi[:, 2] = np.abs(wi[:, 2]); wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = rng.normal(size=(40, 3)); wo[:, 2] = np.abs(wo[:, 2]); wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    m = measure(mat)
    m["gloss"] = float(m["gloss"])
    script = tmp_path / "t.mjs"
    script.write_text(
        f"import {{ evalLobes, exportMeasurements }} from {json.dumps(JS.as_uri())};\n"
        f"const m = {json.dumps(mat.model_dump())}; const wi = {json.dumps(wi.tolist())}; const wo = {json.dumps(wo.tolist())};\n"
        f"const meas = {json.dumps(m)};\n"
        "console.log(JSON.stringify({f: wi.map((a, i) => evalLobes(m, a, wo[i])), csv: exportMeasurements(meas, 'csv'),"
        " json: JSON.parse(exportMeasurements(meas, 'json'))}));\n")
    out = json.loads(subprocess.run(["node", str(script)], capture_output=True, text=True, check=True).stdout)
    assert np.allclose(out["f"], evaluate(mat, wi, wo), rtol=1e-5)
    py_csv = export_measurements(m, "csv").splitlines()
    js_csv = out["csv"].splitlines()
    assert js_csv[0] == py_csv[0] and len(js_csv) == len(py_csv)
    for a, b in zip(js_csv[1:], py_csv[1:]):
        fa, fb = a.split(","), b.split(",")
        assert fa[:2] == fb[:2]
        assert np.allclose([float(x) for x in fa[2:] if x], [float(x) for x in fb[2:] if x], rtol=1e-5)
    assert out["json"]["aspecular"].keys() == m["aspecular"].keys()
