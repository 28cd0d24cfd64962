"""The one module that imports jinja2: the console's HTML templates (gateway/sinks/web/templates/).

jinja2 rather than string formatting because the pages show text that others
choose: variable and alarm texts from the controller, user names, file names,
audit values. Its autoescaping makes every one of them text, never markup, so a
program called `<script>….nc` cannot run in an operator's browser. It is a small,
long-lived library with no dependency of its own but MarkupSafe.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gateway.errors import SinkError

if TYPE_CHECKING:
    from jinja2 import Environment

FOLDER = Path(__file__).with_name("templates")


class Templates:
    """The templates of `folder`, with `filters`; jinja2 is imported, and the environment made, for the
    first page (a gateway whose console nobody opens does not carry it: 1.2 MB)."""

    def __init__(
        self, folder: Path = FOLDER, filters: Mapping[str, Callable[..., Any]] | None = None
    ) -> None:
        self.folder = folder
        self.filters = dict(filters or {})
        self._env: Environment | None = None

    @property
    def env(self) -> Environment:
        if self._env is None:
            from jinja2 import Environment, FileSystemLoader, StrictUndefined

            env = Environment(
                loader=FileSystemLoader(self.folder),
                autoescape=True,
                undefined=StrictUndefined,
                trim_blocks=True,
                lstrip_blocks=True,
            )
            env.filters.update(self.filters)
            self._env = env
        return self._env

    def render(self, name: str, **context: Any) -> str:
        from jinja2 import TemplateError

        try:
            return self.env.get_template(name).render(**context)
        except TemplateError as exc:  # a bug in a template: the handler's caller logs it, as any other
            raise SinkError(f"web console template {name}: {exc}") from exc
