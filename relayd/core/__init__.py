"""The pure decision core: events in, actions out.

Nothing under relayd.core does I/O, reads a clock or imports asyncio, aiohttp, structlog,
pydantic or serial (tests/system/test_imports.py checks it in a fresh interpreter, and the
import-linter contract in pyproject.toml keeps the layers). The brain (brain.py) folds the
typed events (events.py) into actions; the sub-packages hold its concepts. The layout and
the import contract are drawn in docs/ARCHITECTURE.md.
"""
