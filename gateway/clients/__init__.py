"""Asyncio clients of controller protocols that a driver and a delivery transport share (FOCAS, Haas MDC).

Each is the one place its protocol meets a socket; the parsing is in gateway/codecs/. Errors are
`SourceError` (the connection) and `FocasRefusal` and the like (the controller said no).
"""
