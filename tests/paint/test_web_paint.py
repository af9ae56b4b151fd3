"""web/js/paint.js: its measurement export agrees with the worker's (its lobe plot and swatches
draw the worker's values: tests/paint/test_swatch.py, tests/web/test_browser.py)."""
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from worker.paint.geometry import export_measurements, measure
from worker.scene import Lobes

JS = Path(__file__).resolve().parents[2] / "web" / "js" / "paint.js"


@pytest.mark.skipif(shutil.which("node") is None, reason="node not installed")
def test_js_export_matches_python(tmp_path):
    mat = Lobes(exponents=[1.0, 12.0, 900.0], gloss=[0.0, 0.01, 0.04],
                directional_diffuse=[(0.2, 0.1, 0.05), (0.3, 0.3, 0.2), (0.0, 0.0, 0.0)], albedo=(0.05, 0.04, 0.03))
    m = measure(mat)
    m["gloss"] = float(m["gloss"])
    script = tmp_path / "t.mjs"
    script.write_text(
        f"import {{ exportMeasurements }} from {json.dumps(JS.as_uri())};\n"
        f"const meas = {json.dumps(m)};\n"
        "console.log(JSON.stringify({csv: exportMeasurements(meas, 'csv'), json: JSON.parse(exportMeasurements(meas, 'json'))}));\n")
    out = json.loads(subprocess.run(["node", str(script)], capture_output=True, text=True, check=True).stdout)
    py_csv = export_measurements(m, "csv").splitlines()
    js_csv = out["csv"].splitlines()
    assert js_csv[0] == py_csv[0] and len(js_csv) == len(py_csv)
    for a, b in zip(js_csv[1:], py_csv[1:]):
        fa, fb = a.split(","), b.split(",")
        assert fa[:2] == fb[:2]
        assert np.allclose([float(x) for x in fa[2:] if x], [float(x) for x in fb[2:] if x], rtol=1e-5)
    assert out["json"]["aspecular"].keys() == m["aspecular"].keys()
