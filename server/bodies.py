"""Request bodies read as they arrive, under a size cap: the declared length is checked first,
then the bytes as they come, so an over-long body is refused without being held."""
from __future__ import annotations

from collections.abc import AsyncIterator

from fastapi import HTTPException, Request
from starlette.requests import ClientDisconnect


async def capped_chunks(request: Request, limit: int, declared_over: str, over: str, cut: str) -> AsyncIterator[bytes]:
    """The body's chunks, at most ``limit`` bytes in all. 413 with ``declared_over`` (formatted
    with ``n``, the declared length) or ``over``; 400 with ``cut`` when the client goes away."""
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > limit:
        raise HTTPException(413, declared_over.format(n=int(declared)))
    size = 0
    try:
        async for chunk in request.stream():
            size += len(chunk)
            if size > limit:
                raise HTTPException(413, over)
            yield chunk
    except ClientDisconnect:
        raise HTTPException(400, cut) from None
