"""The docs' tables of plugins are the registry's: ``invrender plugins`` prints them, and
docs/plugins.md holds exactly its output in its generated regions (regenerate with
``invrender plugins --docs docs/plugins.md``)."""

from __future__ import annotations

from pathlib import Path

from invrender.cli import main
from invrender.cli.plugins import fill, tables

DOCS = Path(__file__).resolve().parents[2] / "docs" / "plugins.md"


def test_docs_plugins_md_holds_the_generated_tables():
    text = DOCS.read_text()
    assert fill(text, tables()) == text, "docs/plugins.md is stale: run 'invrender plugins --docs docs/plugins.md'"


def test_the_tables_list_every_registered_plugin_with_its_keys():
    t = tables()
    assert "| `glossy` | GGX rough conductor" in t["materials"] and "`roughness` alpha in (0, 1], default 0.1 (one number or texture)" in t["materials"]
    assert "| `area` |" in t["emitters"] and "the shapes naming it" in t["emitters"]
    assert all(f"| `{name}` |" in t["integrators"] for name in ("path", "random_walk", "utah", "whitted", "distributed", "radiosity"))
    assert "`rr_depth` = `5`" in t["integrators"]


def test_the_command_prints_and_fills(tmp_path, capsys):
    assert main(["plugins"]) == 0
    assert "## materials" in capsys.readouterr().out
    page = tmp_path / "p.md"
    page.write_text("".join(f"x\n<!-- begin: {n} table (generated) -->\nold\n<!-- end: {n} table (generated) -->\n" for n in ("materials", "emitters", "integrators")))
    assert main(["plugins", "--docs", str(page)]) == 0
    assert "old" not in page.read_text() and "| `diffuse` |" in page.read_text()


def test_a_page_without_the_regions_is_a_one_line_error(tmp_path, capsys):
    page = tmp_path / "p.md"
    page.write_text("no regions\n")
    assert main(["plugins", "--docs", str(page)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("invrender: error:") and "materials table (generated)" in err and "\n" not in err
    assert page.read_text() == "no regions\n"
    assert main(["plugins", "--docs", str(tmp_path / "missing.md")]) == 2
