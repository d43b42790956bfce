"""The README, docs/ and the READMEs of results/: every relative link and every repository path
they name exists, every ``dockingrl`` command they quote parses, every result folder says what
made it, and the README stays short."""

import functools
import glob
import json
import re
import shlex
from pathlib import Path

import pytest
import torch

from dockingrl.cli import build_parser
from dockingrl.cli.arguments import UsageError

ROOT = Path(__file__).resolve().parents[1]
README_MAX_LINES = 120
README_MAX_WIDTH = 120
#: inline code that starts with one of these is a repository path
PATH_PREFIXES = ("results/", "docs/", "dockingrl/", "scripts/", "bench/", "tests/")

FENCE = re.compile(r"^\s*(```|~~~).*?^\s*\1", re.S | re.M)
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
CODE = re.compile(r"(`+)(.+?)\1", re.S)
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$", re.M)


def documents() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def documents_with_commands() -> list[Path]:
    return [*documents(), *sorted((ROOT / "results").rglob("*.md"))]


def prose(text: str) -> str:
    """The text without its fenced code blocks (commands there are not links)."""
    return FENCE.sub("", text)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    text = re.sub(r"[`*_]|\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    return re.sub(r"\s", "-", re.sub(r"[^\w\- ]", "", text))


def expand(path: str) -> list[str]:
    """``a/{b,c}.d`` -> ``a/b.d``, ``a/c.d`` (one brace group at a time)."""
    match = re.search(r"\{([^{}]*)\}", path)
    if not match:
        return [path]
    head, tail = path[: match.start()], path[match.end() :]
    return [p for part in match.group(1).split(",") for p in expand(head + part + tail)]


def exists(path: Path) -> bool:
    if any(c in str(path) for c in "*?["):
        return bool(glob.glob(str(path)))
    return path.exists()


def broken_links(doc: Path) -> list[str]:
    """Relative links of ``doc`` whose file, folder or anchor (on this page or another
    Markdown page) does not exist."""
    text = doc.read_text()
    bad = []
    for target in LINK.findall(prose(text)):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):
            continue  # https:, mailto:
        path, _, anchor = target.partition("#")
        page = doc.parent / path if path else doc
        if path and not exists(page):
            bad.append(f"{doc.name}: link {target} does not resolve")
        elif anchor and page.suffix == ".md" and anchor not in anchors(page):
            bad.append(f"{doc.name}: anchor #{anchor} names no heading of {page.name}")
    return bad


def anchors(page: Path) -> set[str]:
    """The anchors of a Markdown page's headings."""
    return {slug(h) for h in HEADING.findall(prose(page.read_text()))}


def code_paths(text: str) -> list[str]:
    """Repository paths quoted as inline code: the first word of a span that starts with one
    of :data:`PATH_PREFIXES`, without a pytest node id or trailing punctuation."""
    paths = []
    for _, span in CODE.findall(prose(text)):
        word = span.strip().split()[0] if span.strip() else ""
        if word.startswith(PATH_PREFIXES):
            paths.append(word.split("::")[0].rstrip(",.;:"))
    return paths


def broken_paths(doc: Path) -> list[str]:
    """Repository paths quoted in ``doc`` that do not exist (from the repository's root)."""
    return [
        f"{doc.name}: `{path}` does not exist"
        for path in code_paths(doc.read_text())
        if not all(exists(ROOT / p) for p in expand(path))
    ]


#: a word that stands for a value the reader fills in (``--seed S``, ``--policy P``, ``...``);
#: :func:`unparsable` also skips a command with a ``<a run>`` placeholder, which may span words
PLACEHOLDER = re.compile(r"^(\.\.\.|[A-Z][A-Z_]*)$")


def fenced_commands(text: str) -> list[str]:
    """The ``dockingrl`` command lines of the fenced code blocks of ``text``: continuation lines
    joined, a leading ``$ `` or ``python -m`` and a trailing ``# comment`` dropped."""
    commands = []
    for block in FENCE.finditer(text):
        for line in block.group(0).replace("\\\n", " ").splitlines():
            line = " ".join(re.sub(r"\s#\s.*$", "", line).split()).removeprefix("$ ")
            line = line.removeprefix("python -m ")
            if line.startswith("dockingrl "):
                commands.append(line)
    return commands


@functools.cache
def parser():
    """``dockingrl``'s parser (built once: parsing leaves it as it was)."""
    return build_parser()


def inline_commands(text: str) -> list[str]:
    """The inline code spans of ``text`` that name a ``dockingrl`` subcommand, whole commands or
    a mention of one option (``dockingrl eval --policy``)."""
    names = set(parser()._subparsers._group_actions[0].choices)
    spans = (" ".join(span.replace("\\", " ").split()) for _, span in CODE.findall(prose(text)))
    return [s for s in spans if s.startswith("dockingrl ") and s.split()[1] in names]


#: what the parser says of a mention that leaves out an option's value or a required option
INCOMPLETE = ("expected one argument", "the following arguments are required")


def unparsable(command: str, *, mention: bool = False) -> str | None:
    """Why ``dockingrl``'s own parser refuses ``command`` (one line), or None. A command with a
    placeholder word is not judged; ``--device cuda`` is judged as on a machine with a GPU. A
    ``mention`` may leave out values and required options, not misspell an option."""
    argv = shlex.split(command)[1:]
    if any(PLACEHOLDER.match(word) for word in argv) or "--help" in argv or "<" in command:
        return None
    try:
        _, extra = parser().parse_known_args(argv)
    except UsageError as exc:
        if mention and any(text in str(exc) for text in INCOMPLETE):
            return None
        return f"{command}: {exc}"
    return f"{command}: unrecognized {' '.join(extra)}" if extra else None


def broken_commands(doc: Path) -> list[str]:
    """The commands of ``doc``'s code blocks and inline code that ``dockingrl`` would refuse,
    with why."""
    text = doc.read_text()
    judged = [unparsable(c) for c in fenced_commands(text)]
    judged += [unparsable(c, mention=True) for c in inline_commands(text)]
    return [why for why in judged if why]


@pytest.mark.parametrize("doc", documents_with_commands(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_command_in_a_document_parses(doc, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    assert broken_commands(doc) == []


def test_the_command_check_finds_an_unknown_option_and_a_bad_value(tmp_path):
    doc = tmp_path / "doc.md"
    doc.write_text(
        "`dockingrl train --no-such-option` and `dockingrl eval --policy` in prose\n"
        "```bash\n$ dockingrl train --recipe sac --scenario compound \\\n  --seed 0  # one run\n"
        "python -m dockingrl train --seed zero\n"
        "dockingrl eval --policy P --episodes 10\n"
        "dockingrl train --init-from runs/<a sac run>\n"
        "dockingrl stress --policy x.pt --no-such-option\n"
        "dockingrl train --help\n```\n"
    )
    assert fenced_commands(doc.read_text()) == [
        "dockingrl train --recipe sac --scenario compound --seed 0",
        "dockingrl train --seed zero",
        "dockingrl eval --policy P --episodes 10",
        "dockingrl train --init-from runs/<a sac run>",
        "dockingrl stress --policy x.pt --no-such-option",
        "dockingrl train --help",
    ]
    assert inline_commands(doc.read_text()) == [
        "dockingrl train --no-such-option",
        "dockingrl eval --policy",
    ]
    bad = broken_commands(doc)
    assert len(bad) == 3
    assert bad[0].startswith("dockingrl train --seed zero: argument --seed")
    assert bad[1:] == [
        "dockingrl stress --policy x.pt --no-such-option: unrecognized --no-such-option",
        "dockingrl train --no-such-option: unrecognized --no-such-option",
    ]


@pytest.mark.parametrize("doc", documents_with_commands(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(doc):
    assert broken_links(doc) == []


@pytest.mark.parametrize("doc", documents_with_commands(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_quoted_repository_path_exists(doc):
    assert broken_paths(doc) == []


#: a backticked command that made a result, and a wall-clock (``969 s``, ``4 min``, ``67.3 h``)
RESULT_COMMAND = re.compile(r"`(?:dockingrl|python|bash) ")
WALL_CLOCK = re.compile(r"\b\d[\d,.]*(?: s| min| h)\b")


def test_every_result_folder_has_a_readme_naming_its_command():
    folders = sorted(p for p in (ROOT / "results").iterdir() if p.is_dir())
    assert folders
    for folder in folders:
        readme = folder / "README.md"
        name = folder.relative_to(ROOT)
        assert readme.is_file(), f"{name} has no README.md"
        text = readme.read_text()
        assert RESULT_COMMAND.search(text), f"{name}/README.md quotes no command"
        assert WALL_CLOCK.search(text), f"{name}/README.md gives no wall-clock"


def test_readme_is_short_and_starts_with_the_set_up_commands():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines"
    wide = [n for n, line in enumerate(lines, 1) if len(line) > README_MAX_WIDTH]
    assert not wide, f"README.md lines {wide} are over {README_MAX_WIDTH} characters"
    assert lines[3].startswith("bash main.sh") and lines[4].startswith("bash test.sh")


def test_the_checks_find_a_broken_link_path_and_anchor(tmp_path):
    (tmp_path / "there.md").write_text("x\n## Using `y -> -y`\n")
    doc = tmp_path / "doc.md"
    doc.write_text(
        "# A title\n[ok](there.md) [gone](missing.md) [web](https://example.org/x)\n"
        "[self](#a-title) [nowhere](#no-such-heading) ![fig](missing.png)\n"
        "[there](there.md#using-y----y) [not there](there.md#using-y---y)\n"
        "`results/no_such_folder/` `docs/choices.md` `results/{table6,nothing}/` "
        "`tests/test_docs.py::test_x` `dockingrl train --out results/x` `README.md`\n"
        "```bash\n[not a link](missing_too.md) `results/in_a_block/`\n```\n"
    )
    assert broken_links(doc) == [
        "doc.md: link missing.md does not resolve",
        "doc.md: anchor #no-such-heading names no heading of doc.md",
        "doc.md: link missing.png does not resolve",
        "doc.md: anchor #using-y---y names no heading of there.md",
    ]
    assert code_paths(doc.read_text()) == [
        "results/no_such_folder/",
        "docs/choices.md",
        "results/{table6,nothing}/",
        "tests/test_docs.py",
    ]
    assert broken_paths(doc) == [
        "doc.md: `results/no_such_folder/` does not exist",
        "doc.md: `results/{table6,nothing}/` does not exist",
    ]


def test_the_readme_examples_import_only_the_public_api():
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks, "README.md has no Python example"
    lines = [line for block in blocks for line in block.splitlines()]
    imports = [line for line in lines if re.match(r"\s*(from|import) ", line)]
    assert imports and all(line.startswith("from dockingrl import ") for line in imports), imports
    import dockingrl

    for line in imports:
        for name in line.removeprefix("from dockingrl import ").split(","):
            assert name.strip() in dockingrl.__all__, name


#: the pages a user reads, each at most :data:`USER_PAGE_MAX_WORDS` words
USER_PAGES = ("user_guide", "reproduction", "realism", "gymnasium", "architecture", "robustness")
USER_PAGE_MAX_WORDS = 3000


@pytest.mark.parametrize("page", USER_PAGES)
def test_a_user_page_is_short(page):
    words = len((ROOT / "docs" / f"{page}.md").read_text().split())
    assert words <= USER_PAGE_MAX_WORDS, f"docs/{page}.md has {words} words"


def test_the_research_notes_are_under_docs_research():
    assert (ROOT / "docs" / "research" / "README.md").is_file()
    assert not (ROOT / "docs" / "research_notes.md").exists()


def test_the_robustness_page_quotes_the_current_lists_of_recipes_levels_and_grids():
    """docs/robustness.md quotes the refusals of an unknown recipe, level and grid, whose lists
    grow with the package."""
    from dockingrl.env.levels import LEVELS
    from dockingrl.grid.files import grid_names
    from dockingrl.recipes import recipe_names

    text = (ROOT / "docs" / "robustness.md").read_text()
    assert f"neither a recipe name ({', '.join(recipe_names())}) nor a YAML file" in text
    assert f"unknown level 'L9'; valid: {', '.join(LEVELS)}`" in text
    assert f"neither a grid name ({', '.join(grid_names())}) nor a file" in text


def test_the_vehicles_page_quotes_the_current_transfer_ranges_of_table6():
    """docs/vehicles.md quotes, per recipe, the range of the Table 6 cells' mean success on the
    Fossen vehicle (F0) (a recipe with one cell: its figure), and the range of the recommended
    recipes' nominal success; both move as the grid's trials come in."""
    text = " ".join((ROOT / "docs" / "vehicles.md").read_text().split())
    cells = json.loads((ROOT / "results" / "table6" / "realistic.json").read_text())["F0"]
    assert cells, "results/table6/realistic.json has no F0 cell"
    for recipe in sorted({cell["recipe"] for cell in cells}):
        means = [cell["success_mean"] for cell in cells if cell["recipe"] == recipe]
        span = f"{min(means):.1f}" if len(means) == 1 else f"{min(means):.1f}-{max(means):.1f}"
        quoted = f"{span} % for `{recipe}`"
        assert quoted in text, f"docs/vehicles.md should quote {quoted!r}"
    nominal = [cell["nominal_mean"] for cell in cells if not cell["recipe"].startswith("paper-")]
    quoted = f"against {min(nominal):.1f}-{max(nominal):.1f} % nominal"
    assert quoted in text, f"docs/vehicles.md should quote {quoted!r}"


def test_the_table6_page_quotes_each_recipe_s_iqm_as_table_json_gives_it():
    """results/table6/README.md quotes each recommended recipe's IQM over its four cells with its
    bootstrap interval; the table is made anew as trials come in, and its (seeded) intervals
    must be the ones quoted."""
    text = " ".join((ROOT / "results" / "table6" / "README.md").read_text().split())
    aggregates = json.loads((ROOT / "results" / "table6" / "table.json").read_text())["aggregates"]
    quoted = [a for a in aggregates if not a["recipe"].startswith("paper-")]
    assert quoted, "results/table6/table.json has no recipe's IQM"
    for a in quoted:
        low, high = a["ci95"]
        figure = f"{a['iqm']:.1f} % [{low:.1f}, {high:.1f}]"
        assert figure in text, f"results/table6/README.md should quote {a['recipe']}'s IQM {figure}"


def _code_names() -> dict[str, list]:
    """Every class and function defined at the top of a dockingrl module, by name (a name
    defined in several modules maps to each)."""
    import importlib
    import inspect
    import pkgutil

    import dockingrl

    names: dict[str, list] = {}
    for info in pkgutil.walk_packages(dockingrl.__path__, "dockingrl."):
        if info.name.endswith("__main__"):  # runs the command line on import
            continue
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if (inspect.isclass(obj) or inspect.isfunction(obj)) and obj.__module__ == info.name:
                names.setdefault(name, []).append(obj)
    return names


def _resolves(reference: str, names: dict[str, list], packages: list[str]) -> bool:
    """Whether ``Name.attr...`` names a dockingrl class's or function's attribute, or
    ``module.Name...`` a module's, the module named from one of ``packages`` (``dockingrl``
    and its packages: ``ekf.ekf_update`` is ``dockingrl.transforms.ekf``'s)."""
    import importlib

    parts = reference.split(".")
    for obj in names.get(parts[0], []):
        for attr in parts[1:]:
            obj = getattr(obj, attr, None)
        if obj is not None:
            return True
    for package in packages:
        for cut in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(f"{package}." + ".".join(parts[:cut]))
            except ImportError:
                continue
            for attr in parts[cut:]:
                obj = getattr(obj, attr, None)
            if obj is not None:
                return True
            break
    return False


def test_the_code_that_choices_md_names_exists():
    """The last column of docs/choices.md names where each choice lives in the code: each
    dotted name there (``Selection.keep_candidate``, ``training.checkpointing.Checkpoints``)
    is a class, function, method, field or module of dockingrl, so a renamed one fails here."""
    import pkgutil

    import dockingrl

    names = _code_names()
    packages = ["dockingrl"] + [
        info.name for info in pkgutil.iter_modules(dockingrl.__path__, "dockingrl.") if info.ispkg
    ]
    missing = set()
    for line in (ROOT / "docs" / "choices.md").read_text().splitlines():
        if not line.startswith("|"):
            continue
        where = line.rstrip().rstrip("|").split("|")[-1]
        for reference in re.findall(r"`([A-Za-z_][\w.]*\.[A-Za-z_]\w*)`", where):
            if not reference.endswith(".py") and not _resolves(reference, names, packages):
                missing.add(reference)
    assert not missing, f"docs/choices.md names code that does not exist: {sorted(missing)}"
