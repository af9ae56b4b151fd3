"""MkDocs hook (mkdocs.yml `hooks:`): writes the generated reference pages before every build, so
a plain `mkdocs build` or `mkdocs serve` works on a fresh clone too. Pages whose text is unchanged
are not rewritten, so `mkdocs serve` does not rebuild in a loop."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gen_reference  # noqa: E402


def on_pre_build(config, **kwargs):
    gen_reference.main(["--out", str(Path(config["docs_dir"]) / "reference")])
