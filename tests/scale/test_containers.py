"""Container files checked without a Docker daemon: hadolint on the Dockerfile,
shellcheck on its entry point, the compose file against the Compose Specification's JSON schema
(vendored in check-jsonschema, no network), and what no schema knows: build targets exist,
every GLINT_* variable is a setting, every node mounts the blob store at the same path, the Ray
workers join the server's head, the database URL names the database service.

Not run here (no daemon on these machines): building the images, starting the compose file."""
import re
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
DOCKER = ROOT / "docker"
BIN = Path(sys.executable).parent


def _run(args):
    return subprocess.run(args, capture_output=True, text=True, cwd=ROOT, timeout=120)


def test_dockerfile_passes_hadolint():
    out = _run([str(BIN / "hadolint"), "--config", str(DOCKER / "hadolint.yaml"), str(DOCKER / "Dockerfile")])
    assert out.returncode == 0, out.stdout + out.stderr


def test_entrypoint_passes_shellcheck():
    out = _run([str(BIN / "shellcheck"), "--shell=sh", str(DOCKER / "entrypoint.sh")])
    assert out.returncode == 0, out.stdout + out.stderr


def test_compose_file_matches_the_compose_specification():
    out = _run([str(BIN / "check-jsonschema"), "--builtin-schema", "vendor.compose-spec", str(DOCKER / "compose.yaml")])
    assert out.returncode == 0, out.stdout + out.stderr


def test_compose_and_images_fit_together():
    from server.config import Settings

    dockerfile = (DOCKER / "Dockerfile").read_text()
    targets = set(re.findall(r"^FROM \S+ AS (\S+)$", dockerfile, re.M))
    compose = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    services = compose["services"]
    entry = (DOCKER / "entrypoint.sh").read_text()
    roles = set(re.findall(r"^  ([a-z-]+)\)$", entry, re.M))

    # every file the Dockerfile copies exists; the extras it installs exist
    for src in re.findall(r"^COPY (?!--from)(\S+)", dockerfile, re.M):
        assert (ROOT / src).exists(), f"COPY {src}: no such file"
    extras = re.search(r"pip install --no-cache-dir '\.\[([a-z,]+)\]'", dockerfile).group(1).split(",")
    pyproject = (ROOT / "pyproject.toml").read_text()
    for e in extras:
        assert re.search(rf"^{e} = \[", pyproject, re.M), f"pyproject.toml has no extra {e!r}"

    # GLINT_* variables anywhere in the container files are settings (no silently ignored typo)
    fields = {f"GLINT_{n.upper()}" for n in Settings.model_fields}
    used = set(re.findall(r"GLINT_[A-Z_]+", dockerfile + entry + (DOCKER / "compose.yaml").read_text()))
    assert used and used <= fields, f"not settings: {sorted(used - fields)}"

    glint_code = {}
    for name, svc in services.items():
        b = svc.get("build")
        if b:
            assert (ROOT / "docker" / b["context"] / b["dockerfile"]).resolve() == (DOCKER / "Dockerfile").resolve()
            assert b["target"] in targets, (name, b["target"], targets)
            glint_code[name] = svc
            assert svc.get("command", ["serve"])[0] in roles, (name, svc.get("command"))
    server = [n for n, s in glint_code.items() if s["build"]["target"] == "server"]
    workers = [n for n, s in glint_code.items() if s["build"]["target"] == "ray-worker"]
    assert len(server) == 1 and len(workers) == 2, (server, workers)
    env = services[server[0]]["environment"]
    assert env["GLINT_BACKEND"] == "ray" and "GLINT_RAY_ADDRESS" not in env      # the server is the head
    url = env["GLINT_DATABASE_URL"]
    assert url.startswith("postgresql+psycopg://") and re.search(r"@([a-z0-9-]+)[:/]", url).group(1) in services
    for w in workers:
        assert services[w]["environment"]["RAY_HEAD"] == server[0]
    # the blob store: one volume at the same path in every container that runs Glint code
    data = {n: s["environment"].get("GLINT_DATA_DIR", "/data") for n, s in glint_code.items()}
    assert set(data.values()) == {"/data"}, data
    mounts = {n: {v.split(":")[1]: v.split(":")[0] for v in s.get("volumes", [])} for n, s in glint_code.items()}
    vols = {m.get("/data") for m in mounts.values()}
    assert len(vols) == 1 and None not in vols and vols <= set(compose["volumes"]), mounts
