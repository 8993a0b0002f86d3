"""The documentation stays a reader's: a short README, links that resolve inside the
repository, a command reference that matches the program, and no narration of how the
code was built (that history belongs in CHANGELOG.md and git)."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
import unicodedata
from pathlib import Path
from urllib.parse import unquote, urlparse

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
README_MAX_LINES = 260

HISTORY_SUFFIXES = (".py", ".md", ".toml", ".sh")
HISTORY_EXEMPT = {"CHANGELOG.md", "tests/test_docs.py"}
"""CHANGELOG.md is where history belongs; this file names the words it looks for."""

_ORDINAL = (
    r"(?:first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|last|previous|"
    r"earlier|this|that|next|\d+(?:st|nd|rd|th))"
)
HISTORY_WORDS: dict[str, re.Pattern[str]] = {
    name: re.compile(pattern, re.IGNORECASE)
    for name, pattern in {
        # a working session of the people who wrote the code (not a Ray, HTTP or pytest one)
        "session": rf"\b{_ORDINAL} (?:working )?sessions?\b|\bsessions? (?:one|two|three|\d+)\b",
        "issue": (
            r"\bissues? #?\d+|\bissue list\b|\b(?:another|a later|the next) issue\b|"
            r"\bthe issue's\b|\b\w+'s issue\b"
        ),
        "engineers": r"\bengineers?\b",
        "round": r"\bround (?:one|two|three|four|five|\d+)\b",
        "we measured": r"\bwe measured\b",
        "previously": r"\bpreviously\b",
        # "used to" as "formerly" (the subject a pronoun); "the seed used to draw" is fine
        "used to": r"\b(?:it|this|that|which|they|we|these|those|there) used to\b|\bused to be\b",
        # "an output's earlier version" is a state of the output, not of the code
        "earlier release": r"\bearlier (?:release|code)s?\b|\ban earlier version of (?:the|this)\b",
        # "processes that no longer run" describes a state, not the code's past
        "no longer": r"\bno longer\b(?! (?:runs?|running|exists?|alive|there)\b)",
        "kept for callers": r"\bkept for (?:the )?(?:callers|compatibility)\b",
        "the old": (
            r"\bthe old (?:way|code|default|implementation|format|layout|behaviou?r|api|"
            r"program|preset|world|table|name|module|package|cli)s?\b|\bthe way before\b"
        ),
        "release history": r"\b(?:before|since|until|in) this (?:release|change)\b|"
        r"\bprevious (?:release|code|implementation)\b",
    }.items()
}
"""Words that narrate how the code was built rather than say what it does."""


def _markdown_pages() -> list[Path]:
    return [README, *sorted(DOCS.glob("*.md"))]


def _prose(text: str) -> str:
    """``text`` without fenced code blocks and inline code spans (their brackets are code)."""
    text = re.sub(r"^(```|~~~).*?^\1[^\n]*$", "", text, flags=re.MULTILINE | re.DOTALL)
    return re.sub(r"(`+)(?:(?!\1).)+?\1", "", text)


_INLINE_LINK = re.compile(
    r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)"
)
_REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$", re.MULTILINE)
_HTML_LINK = re.compile(r"""<(?:a|img)\b[^>]*?\b(?:href|src)\s*=\s*["']([^"']+)["']""", re.I)


def _links(page: Path) -> list[str]:
    text = _prose(page.read_text())
    return [
        *_INLINE_LINK.findall(text),
        *_REFERENCE.findall(text),
        *_HTML_LINK.findall(text),
    ]


def _is_external(target: str) -> bool:
    scheme = urlparse(target).scheme
    return scheme in {"http", "https", "mailto"}


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading."""
    text = re.sub(r"<[^>]+>", "", heading)
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", text)
    text = text.replace("`", "").strip().lower()
    kept = "".join(c for c in text if c in " -_" or unicodedata.category(c)[0] in {"L", "N"})
    return kept.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = re.sub(r"^(```|~~~).*?^\1[^\n]*$", "", page.read_text(), flags=re.MULTILINE | re.DOTALL)
    seen: dict[str, int] = {}
    anchors = set()
    for heading in re.findall(r"^#{1,6}\s+(.+?)\s*#*\s*$", text, flags=re.MULTILINE):
        slug = _slug(heading)
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        anchors.add(slug if count == 0 else f"{slug}-{count}")
    return anchors


def _bad_link(page: Path, target: str) -> str | None:
    """Why ``target`` (a link on ``page``) does not resolve inside the repository, or None."""
    if _is_external(target):
        return None
    parsed = urlparse(target)
    if parsed.scheme or parsed.netloc:
        return "leaves the repository (a scheme other than http, https or mailto)"
    path, anchor = unquote(parsed.path), parsed.fragment
    if path.startswith("/"):
        return "leaves the repository by an absolute path"
    resolved = (page.parent / path).resolve() if path else page
    if resolved != ROOT and ROOT not in resolved.parents:
        return "leaves the repository by path"
    if not resolved.exists():
        return "no such file in the repository"
    if anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved):
        return f"no heading #{anchor} in {resolved.relative_to(ROOT)}"
    return None


def test_readme_is_short() -> None:
    lines = README.read_text().count("\n")
    assert lines <= README_MAX_LINES, (
        f"README.md has {lines} lines, at most {README_MAX_LINES}: move detail to docs/"
    )


@pytest.mark.parametrize("page", _markdown_pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_links_resolve_inside_the_repository(page: Path) -> None:
    bad = [
        f"{page.relative_to(ROOT)}: ({target}): {why}"
        for target in _links(page)
        if (why := _bad_link(page, target)) is not None
    ]
    assert not bad, "broken links:\n" + "\n".join(bad)


def test_link_checker_catches_what_it_should(tmp_path: Path) -> None:
    page = DOCS / "maps.md"
    assert _bad_link(page, "../../shared/method.md") == "leaves the repository by path"
    assert _bad_link(page, "/etc/hostname") == "leaves the repository by an absolute path"
    assert _bad_link(page, "file:///etc/hostname") is not None
    assert _bad_link(page, "missing.md") == "no such file in the repository"
    assert _bad_link(page, "store.md#no-such-heading") is not None
    assert _bad_link(page, "store.md#map-tables") is None
    assert _bad_link(page, "#measures") is None
    assert _bad_link(page, "https://rerun.io") is None
    assert _slug("Set-up on a fresh machine (Debian, Python 3.11, CPU)") == (
        "set-up-on-a-fresh-machine-debian-python-311-cpu"
    )
    assert _slug("The sample world (`care sample make`)") == "the-sample-world-care-sample-make"
    fenced = tmp_path / "x.md"
    fenced.write_text("```\n[a](nowhere.md)\n```\n`[b](nowhere.md)` [c](#x)\n# X\n")
    assert _links(fenced) == ["#x"]


def _load(path: Path):
    """A script of the checkout (not an installed package) as a module."""
    spec = importlib.util.spec_from_file_location(path.stem, path)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _cli_reference():
    return _load(ROOT / "scripts" / "cli_reference.py")


def test_cli_reference_is_current() -> None:
    expected = _cli_reference().render()
    page = DOCS / "cli.md"
    assert page.exists(), "docs/cli.md is missing: run python scripts/cli_reference.py"
    assert page.read_text() == expected, (
        "docs/cli.md is out of date with the commands: run python scripts/cli_reference.py"
    )


BENCH_SECTIONS = (
    "ingest", "encode", "world", "fuse", "scale", "query", "paths", "cold_query", "batch",
    "dataset", "travel", "append",
)  # fmt: skip
"""The sections of docs/benchmarks.md, each written by ``bench/<name>.py``."""


def _docs_section():
    return _load(ROOT / "bench" / "docs_section.py")


def test_benchmark_sections(tmp_path: Path) -> None:
    docs_section = _docs_section()
    page = tmp_path / "benchmarks.md"
    page.write_text((DOCS / "benchmarks.md").read_text())
    for name in BENCH_SECTIONS:
        assert (ROOT / "bench" / f"{name}.py").is_file(), name
        body = docs_section.read_section(name, page)
        assert body.startswith(("|", "`python3 bench/")), name
        source = (ROOT / "bench" / f"{name}.py").read_text()
        assert f'recorded("{name}"' in source, f"bench/{name}.py does not write its section"
    before = {name: docs_section.read_section(name, page) for name in BENCH_SECTIONS}
    text = page.read_text()
    docs_section.write_section("fuse", "| a |\n| --- |\n| 1 |\n", page)
    assert docs_section.read_section("fuse", page) == "| a |\n| --- |\n| 1 |"
    for name in BENCH_SECTIONS:
        if name != "fuse":
            assert docs_section.read_section(name, page) == before[name]
    docs_section.write_section("fuse", before["fuse"], page)
    assert page.read_text() == text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["benchmarks.md"]  # nothing staged left
    with pytest.raises(ValueError, match="bench:nosuch"):
        docs_section.write_section("nosuch", "x", page)


def test_a_bench_run_writes_what_it_printed(tmp_path: Path, monkeypatch, capsys) -> None:
    """A run that ends puts what it printed, under its command line, into its section; a
    failed run and a run with ``write=False`` leave the page as it was."""
    docs_section = _docs_section()
    page = tmp_path / "benchmarks.md"
    page.write_text("intro\n<!-- bench:fuse -->\nold\n<!-- /bench:fuse -->\nend\n")
    monkeypatch.setattr(sys, "argv", ["bench/fuse.py", "--frames", "3"])

    def failing_run() -> None:
        with docs_section.recorded("fuse", page=page):
            print("half a table")
            raise RuntimeError

    with pytest.raises(RuntimeError):
        failing_run()
    with docs_section.recorded("fuse", write=False, page=page):
        print("a trial")
    assert docs_section.read_section("fuse", page) == "old"
    with docs_section.recorded("fuse", page=page):
        print("views/s: 31.5")
    assert "views/s: 31.5" in capsys.readouterr().out  # still printed
    body = docs_section.read_section("fuse", page)
    assert body.startswith("`python3 bench/fuse.py --frames 3`")
    assert "```text\nviews/s: 31.5\n```" in body
    assert page.read_text().startswith("intro\n")
    assert page.read_text().endswith("end\n")
    printed = "maps: 3\n## goal poses\n| a | b |\n| --- | --- |\n| 1 | 2 |\nratio x2\n"
    assert docs_section.as_markdown(printed) == (
        "```text\nmaps: 3\n```\n\n**goal poses**\n\n| a | b |\n| --- | --- |\n| 1 | 2 |"
        "\n\n```text\nratio x2\n```"
    )


def _repository_files() -> list[str]:
    try:
        listed = subprocess.run(
            ["git", "ls-files", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT, capture_output=True, text=True, check=True,
        ).stdout.splitlines()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: no list of the repository's files")
    return sorted(
        name
        for name in set(listed)
        if name.endswith(HISTORY_SUFFIXES)
        and name not in HISTORY_EXEMPT
        and (ROOT / name).is_file()
    )


def history_hits(names: list[str]) -> list[str]:
    """``file:line: word: text`` for every line of ``names`` that narrates history."""
    hits = []
    for name in names:
        try:
            lines = (ROOT / name).read_text(errors="replace").splitlines()
        except OSError:
            continue
        for number, line in enumerate(lines, 1):
            for word, pattern in HISTORY_WORDS.items():
                if pattern.search(line):
                    hits.append(f"{name}:{number}: {word}: {line.strip()[:120]}")
    return hits


def test_no_history_in_code_or_docs() -> None:
    hits = history_hits(_repository_files())
    assert not hits, (
        "lines that narrate how the code was built (say what the code does; history goes "
        "in CHANGELOG.md):\n" + "\n".join(hits)
    )


_SPELLED = {"S": "ses" + "sion", "I": "is" + "sue", "E": "engi" + "neers"}
"""The words the narrating examples below need, spelled in pieces: the examples are made up,
and this file holds no line that reads as the project's own history."""


@pytest.mark.parametrize(
    ("template", "narrates"),
    [
        ("until the second {S} the parser skipped blank rows", True),
        ("Third {S} (a faster tokenizer)", True),
        ('@pytest.fixture(scope="session")', False),
        ("One local Ray for the whole test session.", False),
        ("rendered once per session at 64x48", False),
        ("Limits ({I} 3): < 2 s", True),
        ("every case of the {I} list covered", True),
        ("a laptop shared with two other {E}", True),
        ("the widest table also read the old way", True),
        ("is staged whole beside the old one and swapped in", False),
        ("leaves the old version or the new", False),
        ("temporaries of processes that no longer run are swept", False),
        ("empty rows no longer count as zero", True),
        ("the fused top-1 class is right", False),
        ("the seed used to draw the biases", False),
        ("it is used to rank candidates", False),
        ("the parser, which used to drop trailing spaces", True),
        ("An output's earlier version and the one a command makes", False),
        ("the files are byte for byte those of the previous code", True),
        ("40 MB before this release", True),
        ("side by side, the way before this script's {I}", True),
        ("The {I}'s threshold on the demo file", True),
        ("a store made before distortion was removed at ingest is stale", False),
    ],
)
def test_history_words(template: str, narrates: bool) -> None:
    line = template.format(**_SPELLED)
    found = [word for word, pattern in HISTORY_WORDS.items() if pattern.search(line)]
    assert bool(found) == narrates, (line, found)
