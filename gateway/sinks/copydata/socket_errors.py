"""Socket errors in the words a person reads in the log and in Status/CopydataTargets.

Shared by the TCP and UDP transports, so that the same fault reads the same
whichever link met it.
"""

from __future__ import annotations

import os


def os_reason(exc: BaseException) -> str:
    """`connection refused`, not `[Errno 111] Connect call failed ('10.0.0.5', 5020)`."""
    if isinstance(exc, TimeoutError):
        return "timed out"
    errno = getattr(exc, "errno", None)
    if errno:
        return os.strerror(errno).lower()
    return getattr(exc, "strerror", None) or str(exc) or exc.__class__.__name__
