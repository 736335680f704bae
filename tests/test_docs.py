"""The documentation site stays complete: its navigation holds every page and
notebook, the API reference every public name, the scenario-file page every table
and key of the schema, and the command-line pages every command and option; the
Python examples of the getting-started page run. (CI builds the site itself with
`mkdocs build --strict`, which fails on a broken link or reference, and opens its
pages offline with `.ci/check_site.py`, whose checks are tested here.)"""

import argparse
import importlib
import importlib.util
import json
import pathlib
import re
import types

import pytest

import elasticoop
from elasticoop import montecarlo
from elasticoop._cli import build_parser
from elasticoop._config.schema import (
    SECTIONS,
    TOP_LEVEL_KEYS,
    MotionCsv,
    PoseTrackingTable,
)

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def nav_entries() -> list[str]:
    """The files named in mkdocs.yml's `nav` (commented lines left out)."""
    text = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    nav = text[text.index("\nnav:") :]
    lines = [line.split("#", 1)[0] for line in nav.splitlines()]
    return re.findall(r"([\w/.-]+\.(?:md|ipynb))\s*$", "\n".join(lines), re.M)


def public_objects(module: types.ModuleType) -> dict[str, object]:
    """The module's public names (`dir`: the package imports some on first use)."""
    values = {name: getattr(module, name) for name in dir(module)}
    return {
        f"{module.__name__}.{name}": value
        for name, value in values.items()
        if not name.startswith("_") and not isinstance(value, types.ModuleType)
    }


def resolve(path: str) -> object:
    """The object at a dotted path such as `elasticoop._analysis.modes.modes`."""
    module, _, name = path.rpartition(".")
    try:
        return getattr(importlib.import_module(module), name)
    except ModuleNotFoundError:  # a class member: resolve its class first
        return getattr(resolve(module), name)


def sections(page: pathlib.Path, level: str) -> dict[str, str]:
    """The page's sections at heading `level` ("##" or "###"): heading -> text."""
    parts = re.split(rf"^{level} (.+)$", page.read_text(encoding="utf-8"), flags=re.M)
    return dict(zip(parts[1::2], parts[2::2]))


def test_nav_holds_every_page_and_notebook():
    entries = nav_entries()
    for entry in entries:
        source = ROOT / entry if entry.startswith("notebooks/") else DOCS / entry
        assert source.is_file(), f"mkdocs.yml's nav names {entry}, which is missing"
    notebooks = {f"notebooks/{p.name}" for p in (ROOT / "notebooks").glob("*.ipynb")}
    pages = {
        str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md") if "hooks" not in p.parts
    }
    missing = sorted((notebooks | pages) - set(entries))
    assert not missing, f"not in mkdocs.yml's nav: {missing}"


def test_api_reference_documents_every_public_name():
    """Every public name of `elasticoop` and `elasticoop.montecarlo` has a `:::`
    entry in docs/api/ (some under the path of their defining module, where a
    submodule of the same name would hide them), and every entry is public."""
    documented = {}
    for page in (DOCS / "api").glob("*.md"):
        for path in re.findall(r"^::: (\S+)", page.read_text(), re.M):
            documented[path] = resolve(path)
    public = public_objects(elasticoop) | public_objects(montecarlo)
    shown = [id(obj) for obj in documented.values()]
    missing = sorted(name for name, obj in public.items() if id(obj) not in shown)
    assert not missing, f"not in docs/api/: {', '.join(missing)}"
    private = sorted(
        path
        for path, obj in documented.items()
        if not any(obj is value for value in public.values())
    )
    assert not private, f"documented but not public: {', '.join(private)}"


def test_scenario_page_documents_every_table_and_key():
    page = DOCS / "scenario_files.md"
    by_heading = sections(page, "###")
    top = by_heading["Top level"]
    assert all(f"`{key}`" in top for key in TOP_LEVEL_KEYS)
    extra_fields = {
        "forces": PoseTrackingTable.model_fields,
        "prescribed": MotionCsv.model_fields,
    }
    for table, (schema, shape) in SECTIONS.items():
        written = {"array": f"[[{table}]]", "by_body": f"[{table}.<body>]"}.get(
            shape, f"[{table}]"
        )
        heading = next((h for h in by_heading if f"`{written}`" in h), None)
        assert heading is not None, f"{page.name}: no section for {written}"
        text = by_heading[heading]
        for key in [*schema.model_fields, *extra_fields.get(table, ())]:
            in_code = re.search(rf"`[^`\n]*\b{key}\b[^`\n]*`", text)
            assert in_code, f"{page.name}, {written}: key '{key}' missing"
    units = sections(page, "##")["Units and names"]
    assert "degrees" in units and "radians" in units


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(
        a for a in parser._actions if isinstance(a, argparse._SubParsersAction)
    )
    return dict(action.choices)


def test_command_line_pages_document_every_command_and_option():
    """Each command has a section `elasticoop NAME` in cli.md or a page of its own,
    docs/cli_NAME.md, that names every one of its options."""
    cli_sections = sections(DOCS / "cli.md", "##")
    in_cli_page = {
        heading.strip("` "): text
        for heading, text in cli_sections.items()
        if heading.startswith("`elasticoop ")
    }
    shared = cli_sections["Options every command takes"]
    for name, parser in subcommands().items():
        own_page = DOCS / f"cli_{name}.md"
        if own_page.is_file():
            text = own_page.read_text(encoding="utf-8")
        else:
            assert f"elasticoop {name}" in in_cli_page, f"command '{name}' undocumented"
            text = in_cli_page[f"elasticoop {name}"]
        for action in parser._actions:
            for option in action.option_strings:
                written = f"`{option}`" in shared or re.search(
                    rf"[`\s]{re.escape(option)}\b", text
                )
                assert written, f"elasticoop {name}: option {option} undocumented"


def test_command_line_pages_give_the_defaults_of_the_help():
    """Where an option's help names its default, the page's line on that option
    names the same one (a page once kept a default the code had changed)."""
    pages = [DOCS / "cli.md", *sorted(DOCS.glob("cli_*.md"))]
    lines = [line for page in pages for line in page.read_text().splitlines()]
    checked = 0
    for parser in subcommands().values():
        for action in parser._actions:
            default = re.search(r"\(default ([^,\s)]+)", action.help or "")
            if default is None:
                continue
            option = action.option_strings[0]
            for line in lines:
                if re.search(rf"`{re.escape(option)}\b", line):
                    written = re.search(r"\(default ([^,\s)]+)", line)
                    assert written, f"{option}: the default is not on its line"
                    assert written.group(1) == default.group(1), (
                        f"{option}: the page says default {written.group(1)}, the "
                        f"help {default.group(1)}"
                    )
                    checked += 1
    assert checked >= 2  # --count of modes, --batch-width of montecarlo


def python_blocks(page: pathlib.Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", page.read_text(), re.M | re.S)


@pytest.mark.slow  # compiles and runs two 3 s simulations and an equilibrium
def test_getting_started_examples_run():
    import matplotlib

    matplotlib.use("Agg")
    blocks = python_blocks(DOCS / "getting_started.md")
    assert len(blocks) == 2
    namespaces = []
    for block in blocks:
        namespace: dict = {}
        exec(compile(block, "getting_started.md", "exec"), namespace)
        namespaces.append(namespace)
    # the second example starts at rest in its equilibrium (the beam does not drop
    # first) and the manipulators lift it by about their 0.2 m
    traj = namespaces[1]["traj"]
    height = traj.y[:, 0, 2] - traj.y[0, 0, 2]
    assert float(height.min()) > -1e-3
    assert 0.15 < float(height[-1]) < 0.25
    assert abs(float(traj.energy_residual()[-1])) < 1e-6


def _check_site():
    """`.ci/check_site.py`, the offline check CI runs on the built site."""
    spec = importlib.util.spec_from_file_location(
        "check_site", ROOT / ".ci" / "check_site.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_site_check_finds_maths_left_as_tex():
    check = _check_site()
    rendered = (
        '<article><p>a spring <span class="arithmatex"><span class="katex">k</span>'
        "</span> and code <code>$HOME</code></p><pre>\\(x\\)</pre></article>"
    )
    assert check.problems_of(rendered) == []
    raw = (
        '<article><p><span class="arithmatex">\\(m + 1\\)</span> bodies</p>'
        '<div class="jp-RenderedMarkdown">$\\theta = \\pi/2$ and $x_i$</div></article>'
    )
    found = check.problems_of(raw)
    assert found[0] == "unrendered formula: '\\\\(m + 1\\\\)'"
    assert "raw TeX left in the text: '$\\\\theta = \\\\pi/2$'" in found
    assert "raw TeX left in the text: '$x_i$'" in found


def test_site_check_names_the_hosts_a_page_asked_for(tmp_path):
    """Requests the page made (its origin as initiator) count; the browser's own
    (no initiator) and the local server's do not."""
    check = _check_site()
    start = 7
    events = [
        {"type": start, "params": {"url": u, "initiator": i}}
        for u, i in [
            ("http://127.0.0.1:8000/index.html", "not an origin"),
            ("http://127.0.0.1:8000/katex.js", "http://127.0.0.1:8000"),
            ("https://cdn.jsdelivr.net/katex.css", "http://127.0.0.1:8000"),
            ("https://accounts.google.com/ListAccounts", "not an origin"),
        ]
    ]
    log = {"constants": {"logEventTypes": {"URL_REQUEST_START_JOB": start}}}
    text = json.dumps({**log, "events": events})
    (tmp_path / "net.json").write_text(text[:-2] + ",")  # cut short at exit
    assert check._hosts_asked(tmp_path / "net.json") == {"cdn.jsdelivr.net"}
