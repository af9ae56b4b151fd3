"""The docs site builds: the reference generators run (CLI parser, openapi.yaml,
stream-schema.json, server/config.py) and `mkdocs build --strict` succeeds with no warning, as `make docs` does.
The generated pages must list every CLI command, REST path and stream message, so a generator
that breaks, or a page that stops covering the code, fails here. About 10 s."""
import json
import os
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
REF = ROOT / "docs" / "reference"


def _run(args, **kw):
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, env=env,
                          timeout=120, **kw)


def test_docs_build_strict_with_generated_references(tmp_path):
    gen = _run(["scripts/gen_reference.py"])
    assert gen.returncode == 0, gen.stderr

    # every command of the CLI has its section in the generated reference
    listed = _run(["scripts/gen_reference.py", "--list-commands"])
    assert listed.returncode == 0, listed.stderr
    leaves = listed.stdout.split("\n")
    leaves = [n for n in leaves if n]
    cli = (REF / "cli.md").read_text()
    assert len(leaves) > 20, leaves
    missing = [n for n in leaves if f"## `{n}`" not in cli]
    assert not missing, f"commands missing from docs/reference/cli.md: {missing}"
    # argparse's help strings escape % as %%: the tables print it as argparse would
    assert "%%" not in cli, [ln for ln in cli.splitlines() if "%%" in ln]
    for core in ("glint serve", "glint render", "glint fit", "glint gi precompute", "glint capture"):
        assert core in leaves

    # every REST path and every stream message, event and frame-header field
    rest = (REF / "rest.md").read_text()
    paths = yaml.safe_load((ROOT / "openapi.yaml").read_text())["paths"]
    assert not [p for p in paths if f"`{p}`" not in rest]
    stream = (REF / "stream.md").read_text()
    schema = json.loads((ROOT / "stream-schema.json").read_text())
    for part in ("client_message", "server_event"):
        for t in schema[part]["discriminator"]["mapping"]:
            assert f"| `{t}` |" in stream, t
    for field in schema["frame_header"]["properties"]:
        assert f"| `{field}` |" in stream, field
    settings = (REF / "settings.md").read_text()
    sys.path.insert(0, str(ROOT))
    try:
        from server.config import Settings
    finally:
        sys.path.pop(0)
    assert not [n for n in Settings.model_fields if f"`GLINT_{n.upper()}`" not in settings]
    assert "issue " not in cli + rest + stream + settings

    site = tmp_path / "site"
    build = _run(["-m", "mkdocs", "build", "--strict", "--site-dir", str(site)])
    assert build.returncode == 0, build.stdout + build.stderr
    for page in ("index.html", "getting-started.html", "reference/cli.html", "reference/rest.html",
                 "reference/stream.html", "reference/settings.html", "science/bibliography.html", "benchmarks/index.html"):
        assert (site / page).is_file(), page
    # the Python reference was rendered from the docstrings (mkdocstrings found the modules)
    python = (site / "reference" / "python.html").read_text()
    for name in ("SessionState", "FrameRequest", "BRDFModel", "SceneFile", "DirectionTree"):
        assert name in python, name
