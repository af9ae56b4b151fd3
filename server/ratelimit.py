"""Rate limits of the public endpoints (publication reads, viewer sessions), per client address.

The ``limits`` package's moving-window limiter with in-memory storage: a moving window counts
the requests of the last 60 s exactly (a fixed window lets a client send twice the limit across
a window's edge; a token bucket would need its own refill arithmetic, which ``limits`` does not
offer in its synchronous API). In memory is enough: one server process holds the counts, and a
restart forgetting them only gives a client one fresh window. slowapi was not used: it is a
decorator layer over the same limiter, whose 429 body and header handling we would override anyway
to name the setting and the measured count.
"""
from __future__ import annotations

import math
import time

from fastapi import HTTPException, Request
from limits import RateLimitItemPerMinute
from limits.storage import MemoryStorage
from limits.strategies import MovingWindowRateLimiter

_storage = MemoryStorage()
_limiter = MovingWindowRateLimiter(_storage)


def check(request: Request, name: str, per_minute: int) -> None:
    """Count one request of the client's address against ``name`` (a settings field, e.g.
    ``viewer_sessions_per_minute``, whose value is ``per_minute``); raise a 429 with
    ``Retry-After`` (whole seconds until the window frees a slot) when it is over."""
    item = RateLimitItemPerMinute(per_minute)
    host = request.client.host if request.client else "?"
    if _limiter.hit(item, name, host):
        return
    reset, _left = _limiter.get_window_stats(item, name, host)
    wait = max(1, math.ceil(reset - time.time()))
    raise HTTPException(429, f"rate limit: more than {per_minute} requests in 60 s from {host} "
                             f"({name}, GLINT_{name.upper()}); retry after {wait} s",
                        headers={"Retry-After": str(wait)})
