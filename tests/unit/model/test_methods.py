from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import pytest

from gateway.errors import ArgumentsMissing, TooManyArguments, TypeMismatch
from gateway.model.context import WriteContext
from gateway.model.methods import Argument, Method
from gateway.model.types import TypeSpec


async def echo(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
    return [f"{ctx.origin}:{args[0]}:{args[1]}"]


METHOD = Method(
    "Programs",
    "Select",
    "select a program",
    (Argument("name", TypeSpec.parse("String")), Argument("copies", TypeSpec.parse("UInt16"))),
    (Argument("result", TypeSpec.parse("String")),),
    echo,
)


async def test_method_checks_and_passes_typed_arguments() -> None:
    assert await METHOD.call(WriteContext("test"), ["part.nc", 2.0]) == ["test:part.nc:2"]


@pytest.mark.parametrize(
    ("args", "error"),
    [
        (["part.nc"], ArgumentsMissing),
        (["a", 1, 2], TooManyArguments),
        ([5, 1], TypeMismatch),
        (["a", -1], TypeMismatch),
    ],
)
async def test_method_refuses_bad_arguments(args: list[Any], error: type) -> None:
    with pytest.raises(error):
        await METHOD.call(WriteContext("test"), args)
