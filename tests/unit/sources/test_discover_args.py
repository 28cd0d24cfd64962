import pytest

from gateway.sources.opcua.discover import discover


async def test_bad_arguments_are_rejected_before_connecting() -> None:
    with pytest.raises(ValueError, match="machine name"):
        await discover("opc.tcp://127.0.0.1:4999/x", machine="Cell 1")
    with pytest.raises(ValueError, match="port"):
        await discover("opc.tcp://127.0.0.1/x", machine="cell-1")
