"""The packages depend on each other one way: glint (the command line's composition) → server,
bench → worker. worker importing server is tested in tests/server/test_session_runtime.py."""
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
IMPORT = r"^\s*(?:from|import)\s+({})\b"

# every command `glint --help` listed before the command line was split into layers
COMMANDS = {"precompute", "render", "fit", "bench", "serve", "token", "openapi", "schema", "db", "assets", "demo",
            "gi", "paint", "capture", "capture-synth", "field", "bench-ray", "export", "nginx-conf", "mesh"}
BENCHMARKS = {"render", "fit", "stream", "load", "move", "recovery", "strokes", "export-recovery", "accuracy", "antialias", "publish",
              "viewer", "first-start"}


def _importers(package: str, names: list[str]) -> list[str]:
    pat = re.compile(IMPORT.format("|".join(names)), re.M)
    return [str(p.relative_to(ROOT)) for p in (ROOT / package).rglob("*.py") if pat.search(p.read_text())]


def test_runtime_packages_import_neither_the_benchmarks_nor_the_composition():
    assert not _importers("worker", ["bench", "glint"])
    assert not _importers("server", ["bench", "glint"])


def test_benchmarks_use_the_service_from_outside():
    """bench stream and load start `glint serve` as a process: no server module is imported."""
    assert not _importers("bench", ["server", "glint"])


def test_code_cites_documents_in_the_repository():
    """The design conventions are docs/design/conventions.md: a citation of "DESIGN.md", a
    document outside the repository, leads a reader of a clone nowhere."""
    found = []
    for folder in ("worker", "server", "glint", "bench", "web", "tests", "scripts", "docker"):
        for p in (ROOT / folder).rglob("*"):
            if p.suffix in {".py", ".js", ".c", ".h", ".html"} and ".cache" not in p.parts and p.name != "test_layers.py":
                found += [f"{p.relative_to(ROOT)}:{i}" for i, line in enumerate(p.read_text(errors="replace").splitlines(), 1)
                          if "DESIGN.md" in line]
    found += [name for name in ("openapi.yaml", "stream-schema.json") if "DESIGN.md" in (ROOT / name).read_text()]
    assert not found, found


def test_every_benchmark_lives_in_the_benchmark_package():
    """A runtime package (worker, server) ships no benchmark: every ``bench`` command (``glint
    bench …``, ``glint gi bench``, ``glint field bench``, ``glint paint bench``) is bench/'s."""
    sys.path.insert(0, str(ROOT))
    from glint.cli import build_parser

    p, runtime = build_parser(), []

    def walk(parser, path):
        import argparse

        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    walk(sub, path + [name])
        fn = parser.get_default("fn")
        if fn is not None and "bench" in " ".join(path).replace("bench-ray", "bench") \
                and not fn.__module__.startswith("bench."):
            runtime.append(f"glint {' '.join(path)}: {fn.__module__}.{fn.__name__}")

    walk(p, [])
    assert not runtime, runtime


def _choices(parser, *path):
    import argparse

    for name in path:
        parser = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[name]
    return set(next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices)


def test_the_composed_command_has_every_command():
    sys.path.insert(0, str(ROOT))
    from glint.cli import build_parser
    from worker.cli import build_parser as worker_parser

    p = build_parser()
    assert _choices(p) == COMMANDS
    assert _choices(p, "bench") == BENCHMARKS
    # worker's own parser (python -m worker.cli) has worker's commands only
    w = _choices(worker_parser())
    assert not w & {"serve", "token", "openapi", "db", "bench-ray"} and {"render", "gi", "capture"} <= w


def test_building_the_parser_loads_no_web_framework():
    """`glint --help` stays quick: the server's commands import FastAPI only when they run."""
    code = "import sys; from glint.cli import build_parser; build_parser(); print('fastapi' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


def test_python_m_glint_is_the_glint_command():
    out = subprocess.run([sys.executable, "-m", "glint", "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for cmd in ("serve", "bench-ray", "render", "openapi"):
        assert cmd in out.stdout


def test_code_cites_papers_not_issue_numbers():
    """Comments, docstrings and help strings name the capability or the paper's equation: a tracker
    number means nothing to someone reading a clone."""
    pat = re.compile(r"\b[Ii]ssues? #?[0-9]+\b")
    found = []
    for folder in ("worker", "server", "glint", "bench", "web", "tests", "scripts", "docker"):
        for p in (ROOT / folder).rglob("*"):
            if p.suffix in {".py", ".js", ".c", ".h", ".html", ".yaml", ".yml", ".sh"} and ".cache" not in p.parts:
                for i, line in enumerate(p.read_text(errors="replace").splitlines(), 1):
                    if pat.search(line) and "pat = re.compile" not in line:
                        found.append(f"{p.relative_to(ROOT)}:{i}: {line.strip()[:100]}")
    for name in ("openapi.yaml", "stream-schema.json", "Makefile", "pyproject.toml"):
        for i, line in enumerate((ROOT / name).read_text().splitlines(), 1):
            if pat.search(line):
                found.append(f"{name}:{i}: {line.strip()[:100]}")
    assert not found, "issue numbers in the code:\n" + "\n".join(found)
