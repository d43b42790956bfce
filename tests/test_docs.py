"""The README and docs/: every relative link and every repository path they name exists, and
the README stays short."""

import glob
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README_MAX_LINES = 150
#: inline code that starts with one of these is a repository path
PATH_PREFIXES = ("results/", "docs/", "dockingrl/", "scripts/", "bench/", "tests/")

FENCE = re.compile(r"^\s*(```|~~~).*?^\s*\1", re.S | re.M)
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
CODE = re.compile(r"(`+)(.+?)\1", re.S)
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$", re.M)


def documents() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


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
    """Relative links of ``doc`` whose file, folder or same-page anchor does not exist."""
    text = doc.read_text()
    anchors = {slug(h) for h in HEADING.findall(prose(text))}
    bad = []
    for target in LINK.findall(prose(text)):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):
            continue  # https:, mailto:
        path, _, anchor = target.partition("#")
        if not path:
            if anchor not in anchors:
                bad.append(f"{doc.name}: anchor #{anchor} names no heading")
            continue
        if not exists(doc.parent / path):
            bad.append(f"{doc.name}: link {target} does not resolve")
    return bad


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


@pytest.mark.parametrize("doc", documents(), ids=lambda p: p.name)
def test_every_relative_link_resolves(doc):
    assert broken_links(doc) == []


@pytest.mark.parametrize("doc", documents(), ids=lambda p: p.name)
def test_every_quoted_repository_path_exists(doc):
    assert broken_paths(doc) == []


def test_readme_is_short_and_starts_with_the_set_up_commands():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines"
    assert lines[3].startswith("bash main.sh") and lines[4].startswith("bash test.sh")


def test_the_checks_find_a_broken_link_path_and_anchor(tmp_path):
    (tmp_path / "there.md").write_text("x")
    doc = tmp_path / "doc.md"
    doc.write_text(
        "# A title\n[ok](there.md) [gone](missing.md) [web](https://example.org/x)\n"
        "[self](#a-title) [nowhere](#no-such-heading) ![fig](missing.png)\n"
        "`results/no_such_folder/` `docs/choices.md` `results/{table6,nothing}/` "
        "`tests/test_docs.py::test_x` `dockingrl train --out results/x` `README.md`\n"
        "```bash\n[not a link](missing_too.md) `results/in_a_block/`\n```\n"
    )
    assert broken_links(doc) == [
        "doc.md: link missing.md does not resolve",
        "doc.md: anchor #no-such-heading names no heading",
        "doc.md: link missing.png does not resolve",
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
