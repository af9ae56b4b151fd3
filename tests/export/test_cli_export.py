"""``glint export`` as a user runs it (subprocess): a Mitsuba folder of the bunny (a Lambert
material: written exactly, no fit), and bad arguments as one-line errors with exit code 2."""
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCENE = str(ROOT / "tests" / "scenes" / "bunny.json")


def glint(*args):
    return subprocess.run([sys.executable, "-m", "glint", *args], capture_output=True, text=True, cwd=ROOT, timeout=600)


def test_glint_export_writes_a_mitsuba_folder_and_reports(tmp_path, shared_assets):
    out = tmp_path / "bunny-mitsuba"
    r = glint("export", SCENE, "--format", "mitsuba", "--out", str(out), "--spp", "32", "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["materials"][0]["exact"] and rep["faces"] == 5648 and rep["path"] == str(out)
    xml = (out / "scene.xml").read_text()
    assert '<integer name="sample_count" value="32" />' in xml and 'type="diffuse"' in xml
    # exporting again replaces the earlier export in place
    assert glint("export", SCENE, "--format", "mitsuba", "--out", str(out)).returncode == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bunny-mitsuba"]


def test_glint_export_bad_input(tmp_path, shared_assets):
    r = glint("export", SCENE, "--format", "gltf", "--out", str(tmp_path / "x.glb"), "--variant", "Gold")
    assert r.returncode == 2 and "expected LABEL=MATERIAL.json" in r.stderr
    r = glint("export", SCENE, "--format", "gltf", "--out", str(tmp_path / "x.glb"), "--variant", "Gold=/nonexistent.json")
    assert r.returncode == 2 and "material file not found" in r.stderr
    bad = tmp_path / "bad.json"
    bad.write_text('{"model": "ggx", "alpha": -1}')
    r = glint("export", SCENE, "--format", "gltf", "--out", str(tmp_path / "x.glb"), "--variant", f"Gold={bad}")
    assert r.returncode == 2 and "variants[0].materials.bunny" in r.stderr
    r = glint("export", SCENE, "--format", "usd", "--out", str(tmp_path / "x.usd"))
    assert r.returncode == 2 and "invalid choice: 'usd'" in r.stderr
    assert not (tmp_path / "x.glb").exists()
