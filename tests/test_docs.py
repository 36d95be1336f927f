"""The documentation does not rot: the MkDocs site builds with warnings as errors (every page in
the navigation, every link and anchor resolves), and every ``virtualgps`` command shown in a
shell block of the README or the docs is one the command line accepts."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from virtualgps.cli import build_parser, join_triples

REPO = Path(__file__).resolve().parents[1]
DOC_FILES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


def shell_commands(text: str) -> list[str]:
    """The ``virtualgps ...`` command lines of a Markdown text's ``sh``/``bash`` blocks, with
    backslash continuations joined and trailing comments removed."""
    out = []
    for block in re.findall(r"```(?:sh|bash|shell|console)\n(.*?)```", text, re.S):
        joined = re.sub(r"\s*\\\n\s*", " ", block)
        for line in joined.splitlines():
            line = line.strip().removeprefix("$ ")
            for part in re.split(r"\s*(?:&&|\|\||;|\|)\s*", line):
                part = part.split(" #", 1)[0].strip()
                if part.startswith("virtualgps "):
                    out.append(part)
    return out


def test_shell_commands_are_found_in_a_block():
    text = ("```sh\npip install . && virtualgps run --poses demo   # the main job\n"
            "virtualgps gap --real a.nmea \\\n   --truth static --out gap/\n```\n"
            "```text\nvirtualgps run [--seed N]\n```\n")
    assert shell_commands(text) == ["virtualgps run --poses demo",
                                    "virtualgps gap --real a.nmea --truth static --out gap/"]


@pytest.mark.parametrize("doc", DOC_FILES, ids=lambda p: p.name)
def test_every_command_in_the_docs_parses(doc):
    commands = shell_commands(doc.read_text())
    parser = build_parser()
    for command in commands:
        argv = join_triples(shlex.split(command)[1:])
        try:
            parser.parse_args(argv)
        except SystemExit as exc:  # argparse's way of refusing (or of --help)
            assert exc.code == 0, f"{doc.name}: `{command}` does not parse"


def test_the_docs_site_builds_without_warnings(tmp_path):
    if shutil.which("mkdocs") is None and not _has_module("mkdocs"):
        if os.environ.get("CI"):
            pytest.fail("mkdocs is missing; the test extra installs it")
        pytest.skip("mkdocs not installed")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir",
                           str(tmp_path / "site")], cwd=REPO, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "site" / "index.html").is_file()


def _has_module(name: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(name) is not None


def _slug(heading: str) -> str:
    """GitHub's (and MkDocs' default) anchor of a Markdown heading."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def test_the_readme_links_to_pages_and_headings_that_exist():
    links = re.findall(r"\]\((docs/[\w\-]+\.md)(?:#([\w\-]+))?\)", (REPO / "README.md").read_text())
    assert links, "the README links into docs/"
    for page, anchor in links:
        path = REPO / page
        assert path.is_file(), page
        if anchor:
            slugs = {_slug(h) for h in re.findall(r"^#+ (.+)$", path.read_text(), re.M)}
            assert anchor in slugs, f"README: {page}#{anchor} names no heading there"


def test_the_tests_and_tools_the_docs_cite_exist():
    """Every ``tests/FILE.py::NAME`` the docs cite (a claim's evidence) names a test that is
    there, and every ``tests/FILE.py`` and ``tools/NAME.py`` is a file: a test moved or renamed
    takes its citations with it (a citation may break across a line, as Markdown wraps it)."""
    cited = files = 0
    for doc in DOC_FILES:
        text = doc.read_text(encoding="utf-8")
        for path, name in re.findall(r"(tests/test_\w+\.py)::\s*(\w+)", text):
            assert re.search(rf"^def {name}\(", (REPO / path).read_text(), re.M), \
                f"{doc.name}: {path}::{name} is no test there"
            cited += 1
        for path in set(re.findall(r"\b(?:tools|tests)/\w+\.(?:py|sh)\b", text)):
            assert (REPO / path).is_file(), f"{doc.name}: {path} is no file"
            files += 1
    assert cited >= 5 and files >= 5, (cited, files)
