"""DESIGN.md is in the repository and the code's references point into it:
every section the code cites by name (``DESIGN.md "GBuffer"``, ``DESIGN.md's
hard cases ("Numerical robustness")``) is a heading of DESIGN.md, every phrase
it quotes (``"the planner ... builds only those buffers, once"``) and every
file it names there (``DESIGN.md ``planner.py````) is in its text.
"""
from __future__ import annotations

import os
import re

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SKIP = {".git", ".venv", "wheels", "dist", "build", "__pycache__", ".pytest_cache", ".hypothesis"}

# a citation: DESIGN.md, up to 20 characters on the same line, then "a section" or
# "a quoted ... phrase"; or DESIGN.md directly followed by ``a name``
CITE = re.compile(r'DESIGN(?:\.md)?[^"`\n]{0,20}"([^"\n]+)"|DESIGN\.md ``([^`\n]+)``')


def _design() -> str:
    with open(os.path.join(ROOT, "DESIGN.md"), encoding="utf-8") as f:
        return f.read()


def _headings(text: str) -> set:
    return {m.group(1).strip() for m in re.finditer(r"^#+ (.+)$", text, re.M)}


def _citations():
    for folder, dirs, files in os.walk(ROOT):
        dirs[:] = [d for d in dirs if d not in SKIP and not d.startswith(".")]   # .venv-5.0, ...: not ours
        for name in files:
            path = os.path.join(folder, name)
            if not name.endswith(".py") or path == os.path.abspath(__file__):
                continue
            with open(path, encoding="utf-8") as f:
                for lineno, line in enumerate(f, 1):
                    for m in CITE.finditer(line):
                        yield f"{os.path.relpath(path, ROOT)}:{lineno}", m.group(1), m.group(2)


def _norm(text: str) -> str:
    return " ".join(text.replace("`", "").split()).lower()


def test_every_cited_section_phrase_and_file_is_in_design_md():
    text = _design()
    heads = {_norm(h) for h in _headings(text)}
    body = _norm(text)
    cites = list(_citations())
    assert len(cites) >= 10                       # the scan finds the code's references
    missing = []
    for where, quoted, named in cites:
        if named is not None:                     # a file or name: in the text
            ok = _norm(named) in body
        elif "..." in quoted:                     # a quoted phrase, shortened
            ok = all(_norm(part) in body for part in quoted.split("...") if part.strip())
        else:                                     # a section name
            ok = _norm(quoted) in heads
        if not ok:
            missing.append(f"{where}: {quoted or named!r}")
    assert not missing, "DESIGN.md lacks what the code cites:\n" + "\n".join(missing)


def test_design_md_states_the_contracts_and_readme_points_at_it():
    heads = _headings(_design())
    for section in ("Layout", "Data model", "What V means", "Light domains", "The pixel model", "Method ids",
                    "Contracts", "Command line", "EXR (naming and layers)", "JSON sidecar", "Farm",
                    "Specified, not implemented yet", "Numerical robustness"):
        assert section in heads, section
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as f:
        assert "DESIGN.md" in f.read()
