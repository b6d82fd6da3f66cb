"""Live view of a running simulation: a Foxglove WebSocket server and a browser page
(docs/live.md). Needs the optional ``foxglove-sdk`` (requirements-live.txt)."""
from .server import check_port, LiveError, LiveServer

__all__ = ['check_port', 'LiveError', 'LiveServer']
