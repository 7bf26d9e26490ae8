"""``invrender plugins``: the registered materials, emitters and integrators as Markdown tables
(type, what it is, parameters with kinds and defaults, constants with ranges, lobes, settings),
generated from the registry; ``--docs FILE`` writes them into a page's marked regions (docs/plugins.md),
so the docs' tables are this command's output and cannot drift from the plugins."""

from __future__ import annotations

import re
from pathlib import Path

from invrender.errors import InvRenderError


def tables() -> dict[str, str]:
    """Region name -> its Markdown table, for every kind of plugin."""
    from invrender.registry import EMITTERS, MATERIALS
    from invrender.scene.plugins import plugin_table
    from invrender.plugins.integrators.base import integrators_table

    return {
        "materials": plugin_table(MATERIALS, ("lobes", lambda cls: cls.lobes.describe())),
        "emitters": plugin_table(EMITTERS, ("emits from", lambda cls: "the shapes naming it" if cls.surface else "outside the scene" if cls.infinite else "a point or a direction (a delta light: sampled, never hit)")),
        "integrators": integrators_table(),
    }


def fill(text: str, generated: dict[str, str]) -> str:
    """``text`` with each region ``<!-- begin: NAME table (generated) -->`` ... ``<!-- end: ... -->``
    holding ``generated[NAME]``; a missing region is an error naming it."""
    for name, body in generated.items():
        pattern = re.compile(rf"(<!-- begin: {name} table \(generated\) -->\n).*?(<!-- end: {name} table \(generated\) -->)", re.S)
        if not pattern.search(text):
            raise InvRenderError(f"no region '<!-- begin: {name} table (generated) -->' ... '<!-- end: {name} table (generated) -->' to fill")
        text = pattern.sub(lambda m: m.group(1) + body + m.group(2), text)
    return text


def add_parser(sub) -> None:
    p = sub.add_parser("plugins", help="the registered materials, emitters and integrators", description=__doc__.split("\n\n")[0])
    p.add_argument("--docs", metavar="FILE", help="write the tables into FILE's marked regions instead of printing them")
    p.set_defaults(run=run)


def run(args) -> int:
    from invrender.io.reports import write_text

    generated = tables()
    if args.docs is None:
        for name, body in generated.items():
            print(f"## {name}\n\n{body}")
        return 0
    path = Path(args.docs)
    try:
        text = path.read_text()
    except OSError as e:
        raise InvRenderError(f"{path}: cannot read: {e.strerror or e}") from None
    write_text(path, fill(text, generated))
    return 0
