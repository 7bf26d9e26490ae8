"""The README is the front door: at most 12 KB, its links lead somewhere, and its install and
quick-start commands are the ones CI (.ci/run) runs, and still work."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
CI = REPO / ".ci" / "run"
MAX_README_BYTES = 12_000

LINK = re.compile(r"\]\(([^)\s]+)\)")


def _section(text: str, title: str) -> str:
    """The body of the README's ``## title`` section."""
    match = re.search(rf"(?ms)^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text)
    assert match, f"README.md has no '## {title}' section"
    return match.group(1)


def _bash_lines(section: str) -> list[str]:
    """The commands of a section's ```bash blocks, one per line (continuations joined)."""
    blocks = re.findall(r"(?ms)^```bash\n(.*?)^```", section)
    lines = "\n".join(blocks).replace("\\\n", " ").splitlines()
    return [" ".join(line.split("#")[0].split()) for line in lines if line.strip() and not line.lstrip().startswith("#")]


def _ci_commands() -> list[str]:
    """The python commands .ci/run runs (apt lines and shell plumbing left out)."""
    lines = CI.read_text().replace("\\\n", " ").splitlines()
    return [" ".join(line.split()) for line in lines if line.strip().startswith("python ")]


def _slug(heading: str) -> str:
    """GitHub's anchor for a Markdown heading."""
    text = re.sub(r"[`*_\[\]()]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = page.read_text()
    anchors = {_slug(h) for h in re.findall(r"(?m)^#+ (.*)$", text)}
    return anchors | set(re.findall(r'<a id="([^"]+)"', text))


def test_readme_is_at_most_12_kb():
    size = README.stat().st_size
    assert size <= MAX_README_BYTES, f"README.md is {size} bytes; at most {MAX_README_BYTES} (move the detail into docs/)"


def test_readme_links_exist():
    text = README.read_text()
    local = [link for link in LINK.findall(text) if not re.match(r"[a-z]+:", link)]
    assert any(link.startswith("docs/") for link in local), "README.md links no page of docs/"
    for link in local:
        path, _, anchor = link.partition("#")
        target = REPO / path if path else README
        assert target.exists(), f"README.md links {link}: {path} does not exist"
        if anchor and target.suffix == ".md":
            assert anchor in _anchors(target), f"README.md links {link}: {path} has no heading #{anchor}"


def test_docs_pages_link_existing_files_and_headings():
    for page in sorted((REPO / "docs").glob("*.md")):
        for link in LINK.findall(page.read_text()):
            if re.match(r"[a-z]+:", link):
                continue
            path, _, anchor = link.partition("#")
            target = page.parent / path if path else page
            assert target.exists(), f"{page.relative_to(REPO)} links {link}: it does not exist"
            if anchor and target.suffix == ".md":
                assert anchor in _anchors(target), f"{page.relative_to(REPO)} links {link}: no heading #{anchor} there"


def test_every_docs_page_is_in_the_readme_map():
    linked = {link.partition("#")[0] for link in LINK.findall(_section(README.read_text(), "Documentation"))}
    for page in sorted((REPO / "docs").glob("*.md")):
        if page.name == "README.md":
            continue
        assert f"docs/{page.name}" in linked, f"docs/{page.name} is missing from README.md's map of the docs"


def test_install_and_test_commands_are_the_ones_ci_runs():
    text = README.read_text()
    ci = _ci_commands()
    ci_install = [c for c in ci if c.startswith("python -m pip install")]
    ci_tests = [c for c in ci if c.startswith("python -m pytest")]
    assert len(ci_install) == 2 and len(ci_tests) == 1, f".ci/run: expected two install commands (torch's CPU build, the package) and one test command, got {ci}"
    assert "--extra-index-url https://download.pytorch.org/whl/cpu" in ci_install[0], f"torch comes from PyTorch's CPU index: {ci_install[0]!r}"
    install = _bash_lines(_section(text, "Install"))
    expected = [c.replace(" --quiet", "") for c in ci_install]
    assert install == expected, f"README's install {install} is not .ci/run's {expected}"
    quick = _bash_lines(_section(text, "Quick start"))
    assert len(quick) == 2, f"the quick start is two commands, not {quick}"
    assert quick[1] == ci_tests[0], f"README's test command {quick[1]!r} is not .ci/run's {ci_tests[0]!r}"
    assert quick[0].startswith("invrender render "), f"the quick start's first command renders: {quick[0]!r}"


def test_quick_start_render_runs(tmp_path):
    """The quick start's render, as written but at 8x8 and 2 spp, into tmp_path."""
    command = _bash_lines(_section(README.read_text(), "Quick start"))[0]
    args = shlex.split(command)[1:]
    small, outputs, i = [], [], 0
    while i < len(args):
        a = args[i]
        if a in ("--spp", "--resolution"):
            small += [a, "2" if a == "--spp" else "8x8"]
            i += 2
            continue
        if a == "--out":
            i += 1
            while i < len(args) and not args[i].startswith("--"):
                outputs.append(args[i])
                i += 1
            continue
        small.append(a)
        i += 1
    assert outputs, f"the quick start's render writes no file: {command!r}"
    small += ["--out", *(str(tmp_path / Path(o).name) for o in outputs)]
    done = subprocess.run([sys.executable, "-m", "invrender", *small], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"{' '.join(small)}: {done.stderr.strip()[-500:]}"
    for o in outputs:
        assert (tmp_path / Path(o).name).stat().st_size > 0


def test_architecture_layout_is_generated_and_current():
    """docs/architecture.md lists the modules by their own docstrings: a moved, added or renamed
    module makes this fail until ``python tools/generate_layout.py`` is run."""
    done = subprocess.run([sys.executable, str(REPO / "tools" / "generate_layout.py"), "--check"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    text = (REPO / "docs" / "architecture.md").read_text()
    for module in ("core/", "plugins/", "backends/", "estimators/", "  driver.py", "  accel.py"):
        assert module in text
