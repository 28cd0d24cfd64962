"""The delivery transports, one module each: how a program reaches a controller."""
