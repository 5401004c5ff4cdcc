"""The user documentation in docs/ says what the code does (issue #28 item 11).

* docs/cli.md is what docs/gen_cli_reference.py makes from the click commands now: change a
  command's options or help, then run ``python docs/gen_cli_reference.py``;
* the python examples of docs/library.md run as printed, in order, in an empty folder;
* the format and algorithm pages name every format, output key and method the code has;
* links between the pages, and the mkdocs nav, point at pages that exist.

docs/ is not part of the installed package: these tests skip when it is absent (a test run
against an installed copy without the source tree). CI runs pytest from the repository root.
"""

import importlib.util
import re
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

pytestmark = pytest.mark.skipif(not (DOCS / "gen_cli_reference.py").is_file(), reason="docs/ is not here")


def _generator():
    spec = importlib.util.spec_from_file_location("rotgraph_docs_gen_cli_reference", DOCS / "gen_cli_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _page(name: str) -> str:
    return (DOCS / name).read_text(encoding="utf-8")


def test_cli_reference_is_current():
    expected = _generator().render()
    actual = (DOCS / "cli.md").read_text(encoding="utf-8") if (DOCS / "cli.md").exists() else ""
    assert actual == expected, "docs/cli.md is stale: run python docs/gen_cli_reference.py"


def test_cli_reference_check_mode(tmp_path, monkeypatch):
    gen = _generator()
    assert gen.main(["--check"]) == 0  # docs/cli.md is current (the test above says why not)
    stale = tmp_path / "cli.md"
    stale.write_text("old\n")
    monkeypatch.setattr(gen, "TARGET", stale)
    assert gen.main(["--check"]) == 1
    assert stale.read_text() == "old\n"  # --check never writes
    assert gen.main([]) == 0 and stale.read_text() == gen.render()


def test_cli_reference_has_every_command_and_option():
    import click

    from rotgraph.cli.main import cli

    text = _page("cli.md")
    commands = [("rotgraph", cli)] + [(f"rotgraph {n}", c) for n, c in cli.commands.items() if not c.hidden]
    for title, cmd in commands:
        heading = f"`{title}`"
        assert re.search(rf"^#+ {re.escape(heading)}$", text, re.M), title
        section = text.split(heading, 1)[1]
        for p in cmd.params:
            if isinstance(p, click.Option) and not p.hidden:
                for opt in p.opts + p.secondary_opts:
                    assert f"`{opt}`" in section, (title, opt)
    for code in (0, 1, 2, 3, 130):
        assert f"\n| {code} |" in text, code


def test_cli_reference_does_not_depend_on_the_terminal(monkeypatch):
    gen = _generator()
    first = gen.render()
    monkeypatch.setenv("COLUMNS", "40")
    monkeypatch.setenv("LINES", "10")
    assert gen.render() == first


@pytest.mark.slow  # its batch example starts a local Dask cluster
def test_library_examples_run(tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", _page("library.md"), re.S)
    assert len(blocks) >= 8
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "library_md"}
    for k, code in enumerate(blocks):
        try:
            exec(compile(code, f"docs/library.md (python block {k + 1})", "exec"), namespace)
        except Exception as exc:  # name the block, not only the line
            raise AssertionError(f"python block {k + 1} of docs/library.md fails: {exc!r}\n{code}") from exc
    out = capsys.readouterr().out
    assert "median error" in out and "component(s)" in out
    assert (tmp_path / "rotations.csv").read_text().startswith("id,name,qw,qx,qy,qz\n")


def test_formats_page_names_every_format_and_key():
    from rotgraph.choices import EDGE_FORMATS, OUTPUT_FORMATS, TABLE_FORMATS
    from rotgraph.estimators.certify import Certificate
    from rotgraph.io.edges import INFORMATION_CSV_COLUMNS, INFORMATION_TEXT_COLUMNS
    from rotgraph.pipeline.batch import MANIFEST_KEYS, SUMMARY_COLUMNS

    text = _page("formats.md")
    names = [f for f in EDGE_FORMATS + OUTPUT_FORMATS + TABLE_FORMATS if f != "auto"]
    names += list(MANIFEST_KEYS) + [f.name for f in fields(Certificate)] + ["relative_gap"]
    names += list(INFORMATION_TEXT_COLUMNS) + list(INFORMATION_CSV_COLUMNS)
    missing = [n for n in names if f"`{n}`" not in text and n not in text]
    assert not missing, f"docs/formats.md does not mention {missing}"
    assert ",".join(SUMMARY_COLUMNS) in text.replace(",\n  ", ",")


def test_algorithms_page_names_every_method():
    from rotgraph.choices import HANDEYE_METHODS, INITS, LOSSES, METHODS, METRICS, NORMS

    text = _page("algorithms.md")
    missing = [n for n in METHODS + LOSSES + METRICS + NORMS + HANDEYE_METHODS + INITS if f"`{n}`" not in text]
    assert not missing, f"docs/algorithms.md does not mention {missing}"


def test_outputs_page_states_the_rule():
    text = _page("outputs.md")
    for k in range(1, 8):
        assert f"### {k}. " in text, k
    assert "exists and is not a rotgraph output (--overwrite replaces it)" in " ".join(text.split())


def test_links_between_pages_resolve():
    pages = sorted(DOCS.glob("*.md"))
    anchors = {p.name: _anchors(p.read_text(encoding="utf-8")) for p in pages}
    for p in pages + [ROOT / "README.md"]:
        for target in re.findall(r"\]\(([^)\s]+)\)", p.read_text(encoding="utf-8")):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            path, _, anchor = target.partition("#")
            resolved = (p.parent / path).resolve()
            assert resolved.exists(), (p.name, target)
            if anchor and resolved.parent == DOCS and resolved.name in anchors:
                assert anchor in anchors[resolved.name], (p.name, target)


def _anchors(text: str) -> set[str]:
    """The heading ids that GitHub and mkdocs both give: GitHub turns each space into '-',
    mkdocs (Python-Markdown's toc) each run of spaces and '-'; a link must work on both."""
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    out = set()
    for heading in re.findall(r"^#+ (.+)$", text, re.M):
        github = re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
        mkdocs = re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", heading).strip().lower())
        if github == mkdocs:
            out.add(github)
    return out


def test_mkdocs_nav_lists_every_page():
    config = ROOT / "mkdocs.yml"
    if not config.exists():
        pytest.skip("no mkdocs.yml")
    nav = set(re.findall(r":\s*([\w.-]+\.md)\s*$", config.read_text(), re.M))
    assert nav == {p.name for p in DOCS.glob("*.md")}


def test_readme_points_to_docs_not_to_missing_files():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    for name in ("CLI.md", "ALGORITHMS.md"):
        assert not (ROOT / name).exists() and f"]({name}" not in readme, name
    assert "docs/" in readme and "rotgraph[all]" in readme


def test_the_documentation_site_builds_strictly(tmp_path):
    """docs/ as a static site with a standard tool (mkdocs, in the test extra): a broken link,
    a page missing from the nav or a nav entry without a page fails the build."""
    pytest.importorskip("mkdocs")
    config = ROOT / "mkdocs.yml"
    out = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "-f", str(config), "-d",
                          str(tmp_path / "site")], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert (tmp_path / "site" / "index.html").is_file() and (tmp_path / "site" / "algorithms" / "index.html").is_file()
