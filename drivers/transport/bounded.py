"""Reading an HTTP answer in pieces, stopping at a size limit (a chunked answer has no length).

`aiohttp`'s `read()` and `json()` take the whole body into memory first; a device or a
peer that streams a gigabyte (a broken radio, a hostile one) would take the daemon's
memory with it. `read_bounded` stops reading, and raises, the moment the limit is passed.
"""

from __future__ import annotations

from typing import Protocol

#: Read this much at a time.
CHUNK_BYTES = 64 * 1024


class BodyTooLarge(ValueError):
    """The answer is larger than the reader's limit (nothing beyond it was read)."""


class _Content(Protocol):
    def iter_chunked(self, n: int) -> object: ...


class _Response(Protocol):
    @property
    def content_length(self) -> int | None: ...

    @property
    def content(self) -> _Content: ...


async def read_bounded(resp: _Response, limit_bytes: int) -> bytes:
    """The whole body, or BodyTooLarge as soon as it passes `limit_bytes`."""
    declared = resp.content_length
    if declared is not None and declared > limit_bytes:
        raise BodyTooLarge(f"answer of {declared} bytes (limit {limit_bytes})")
    parts: list[bytes] = []
    size = 0
    async for chunk in resp.content.iter_chunked(CHUNK_BYTES):  # type: ignore[attr-defined]
        size += len(chunk)
        if size > limit_bytes:
            raise BodyTooLarge(f"answer of more than {limit_bytes} bytes")
        parts.append(chunk)
    return b"".join(parts)
