"""The README's two commands do all set-up on a fresh machine (`make test` must not
depend on .ci/run having installed Chromium first)."""
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_readme_opens_with_make_serve_and_make_test():
    head = (ROOT / "README.md").read_text().split("\n## ")[0]
    assert "make serve" in head and "make test" in head, head[:400]


def test_make_test_installs_the_browser_it_needs():
    """`make test` (dry run) runs the Chromium set-up before pytest, so the browser tests do not
    error on a machine without Chromium."""
    out = subprocess.run(["make", "-n", "test"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    lines = out.splitlines()
    setup = [i for i, l in enumerate(lines) if "ensure-chromium" in l]
    tests = [i for i, l in enumerate(lines) if re.search(r"-m pytest", l)]
    assert setup and tests and setup[0] < tests[0], out
    script = (ROOT / "scripts" / "ensure-chromium").read_text()
    assert "apt-get install" in script and "chromium" in script


def test_test_modules_have_unique_names():
    """Test folders are not packages: two modules with one basename cannot both be collected
    in one run (pytest's prepend import mode), which only a whole-suite run shows."""
    names = [p.name for p in (ROOT / "tests").rglob("test_*.py")]
    dup = sorted({n for n in names if names.count(n) > 1})
    assert not dup, f"test modules share a name: {dup}"
