"""The one module that imports jinja2: the console's HTML templates (gateway/sinks/web/templates/).

jinja2 rather than string formatting because the pages show text that others
choose: variable and alarm texts from the controller, user names, file names,
audit values. Its autoescaping makes every one of them text, never markup, so a
program called `<script>….nc` cannot run in an operator's browser. It is a small,
long-lived library with no dependency of its own but MarkupSafe.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jinja2 import Environment, FileSystemLoader, StrictUndefined, TemplateError

from gateway.errors import SinkError

FOLDER = Path(__file__).with_name("templates")


class Templates:
    def __init__(self, folder: Path = FOLDER) -> None:
        self.env = Environment(
            loader=FileSystemLoader(folder),
            autoescape=True,
            undefined=StrictUndefined,
            trim_blocks=True,
            lstrip_blocks=True,
        )

    def render(self, name: str, **context: Any) -> str:
        try:
            return self.env.get_template(name).render(**context)
        except TemplateError as exc:  # a bug in a template: the handler's caller logs it, as any other
            raise SinkError(f"web console template {name}: {exc}") from exc
