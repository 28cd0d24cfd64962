"""Keep asyncua's client logs short: one line each, never a stack trace.

asyncua logs full tracebacks for conditions the OPC UA driver already reports in
one readable line (a controller switched off, a dropped socket). Users read the
driver's lines; asyncua's stay available, shortened, for debugging.
"""

from __future__ import annotations

import logging


class _OneLine(logging.Filter):
    """Turns an asyncua record with a traceback into one line: the message and the exception."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.exc_info and record.exc_info[1] is not None:
            exc = record.exc_info[1]
            record.msg = f"{record.getMessage()} ({type(exc).__name__}: {exc})"
            record.args = None
            record.exc_info = None
            record.exc_text = None
        return True


_ONE_LINE = _OneLine()
_ASYNCUA_LOGGERS = (
    "asyncua.client.client",
    "asyncua.client.ua_client",
    "asyncua.client.ua_client.UaClient",
    "asyncua.client.ua_client.UASocketProtocol",
    "asyncua.client.ua_session",
    "asyncua.client.ua_session.UaSession",
    "asyncua.common.subscription",
    "asyncua.common.connection",
)


def quiet_asyncua_logging(level: int | None = logging.ERROR) -> None:
    """asyncua's client logs at `level` or above (None: leave the level alone), one line each.

    The OPC UA driver calls this on import with ERROR unless the application set
    the `asyncua` logger's level first; the app may call it again at any time.
    """
    if level is not None:
        logging.getLogger("asyncua").setLevel(level)
    names = set(_ASYNCUA_LOGGERS) | {
        n for n in logging.root.manager.loggerDict if n.startswith("asyncua.client")
    }
    for name in names:
        logger = logging.getLogger(name)
        if _ONE_LINE not in logger.filters:
            logger.addFilter(_ONE_LINE)
