"""forest's render job service: HTTP API, durable SQLite queue, local and Ray executors, web page.

Start it with ``forest serve``; :func:`forest.service.app.create_app` builds the ASGI app.
"""
