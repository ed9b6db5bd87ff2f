"""The HTTP API, one router per concern (see :mod:`forest.service.app`)."""
