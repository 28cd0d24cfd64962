"""gateway/shims/loop.py: which event loop the gateway runs on."""

from __future__ import annotations

import asyncio

import pytest

from gateway.shims.loop import ENV, loop_factory, loop_name, run, uvloop_factory


async def _running_loop_type() -> str:
    return type(asyncio.get_running_loop()).__module__


def test_asyncio_is_asyncio_own_loop(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(ENV, raising=False)
    factory = loop_factory("asyncio")
    assert factory is None and loop_name(factory) == "asyncio"
    assert run(_running_loop_type(), factory).startswith("asyncio")


def test_asyncio_is_the_default_auto_takes_uvloop_when_installed_and_the_environment_can_choose(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv(ENV, raising=False)
    uv = uvloop_factory()
    assert loop_factory() is None
    assert loop_factory("auto") is uv
    monkeypatch.setenv(ENV, "auto")
    assert loop_factory() is uv
    if uv is not None:
        assert run(_running_loop_type(), loop_factory("uvloop")).startswith("uvloop")


def test_an_unknown_loop_or_a_missing_uvloop_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ValueError, match="choose one of auto, asyncio, uvloop"):
        loop_factory("trio")
    monkeypatch.setattr("gateway.shims.loop.uvloop_factory", lambda: None)
    with pytest.raises(ValueError, match="not installed"):
        loop_factory("uvloop")
    assert loop_factory("auto") is None  # auto falls back to asyncio's own
