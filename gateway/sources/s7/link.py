"""One connection to one S7 PLC, through python-snap7: the adapter, and the only module that imports it.

snap7 does what is tedious and well tested there: the TCP connection, ISO-on-TCP (TPKT, COTP), and the
Setup Communication that negotiates the PDU size. The Read Var and Write Var PDUs are the gateway's own
(gateway/codecs/s7/pdu.py): snap7's AsyncClient reads several variables one request each, while a CPU
answers up to 20 in one PDU, so the driver hands its PDUs to `iso_exchange_buffer`. snap7's errors
become `LinkLost` here (a timeout: BadTimeout; the rest: BadNotConnected); snap7's own INFO lines (one
per client made) go to DEBUG, the driver reports the connection itself.
"""

from __future__ import annotations

import asyncio
import logging

import snap7
from snap7.error import S7Error, S7TimeoutError

from gateway.errors import SourceError
from gateway.shims.cancel import deliver_cancel

log = logging.getLogger("gateway.sources.s7")


class _Demote(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING:
            record.levelno, record.levelname = logging.DEBUG, "DEBUG"
        return True


logging.getLogger("snap7.async_client").addFilter(_Demote())


class LinkLost(SourceError):
    """The connection cannot be used any more."""


class S7Link:
    def __init__(self, host: str, port: int, rack: int, slot: int, timeout: float, pdu_size: int) -> None:
        self.host = host
        self.port = port
        self.rack = rack
        self.slot = slot
        self.timeout = timeout
        self.requested = pdu_size
        self.pdu_size = pdu_size
        self.exchanges = 0
        self._client: snap7.AsyncClient | None = None
        self._sequence = 0

    def next_sequence(self) -> int:
        self._sequence = self._sequence % 0xFFFF + 1
        return self._sequence

    @property
    def connected(self) -> bool:
        return self._client is not None and self._client.get_connected()

    async def connect(self) -> None:
        await self.close()
        client = snap7.AsyncClient()
        client.pdu_length = self.requested
        self._client = client
        try:
            async with asyncio.timeout(self.timeout):
                await client.connect(self.host, self.rack, self.slot, self.port)
        except (S7Error, OSError, TimeoutError) as exc:
            await self.close()
            reason = f"cannot connect to {self.host}:{self.port} (rack {self.rack}, slot {self.slot})"
            detail = str(exc) or type(exc).__name__
            raise LinkLost(f"{reason}: {detail}", status="BadNotConnected") from None
        if client.connection is not None:
            client.connection.timeout = self.timeout
        self.pdu_size = int(client.pdu_length)

    async def close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            try:
                async with asyncio.timeout(1.0):
                    await client.disconnect()
            except (S7Error, OSError, TimeoutError):
                pass

    async def exchange(self, pdu: bytes) -> bytes:
        """Send one S7 PDU, return the PLC's answer."""
        client = self._client
        if client is None or not client.get_connected():
            raise LinkLost(f"not connected to {self.host}:{self.port}", status="BadNotConnected")
        self.exchanges += 1
        try:
            answer = await client.iso_exchange_buffer(bytearray(pdu))
            deliver_cancel()  # a cancel snap7's wait_for swallowed (Python 3.11)
        except S7TimeoutError:
            raise LinkLost(f"no answer from {self.host}:{self.port} within {self.timeout:g} s",
                           status="BadTimeout") from None  # fmt: skip
        except (S7Error, OSError) as exc:
            raise LinkLost(f"{self.host}:{self.port}: {exc}", status="BadNotConnected") from None
        return bytes(answer)
