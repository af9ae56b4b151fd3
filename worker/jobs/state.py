"""Compatibility: the session protocol moved to ``worker.protocol`` (state, messages, effects,
events, wire). Kept for modules outside the session code that still import it from here
(worker/cli.py, worker/bench_stream.py); new code imports ``worker.protocol``."""
from ..protocol import *  # noqa: F401,F403
from ..protocol import _MESSAGES  # noqa: F401
