"""``python -m glint …`` is ``glint …`` (what tests and scripts run from a clone)."""
import sys

from .cli import main

sys.exit(main())
