"""The README is the front door: short, its tables those of bench/results/,
and every command-line option it shows one the parser takes."""
import os
import re

from penumbra import cli
from penumbra.bench import readme_tables

README = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "README.md")


def _text():
    with open(README, encoding="utf-8") as f:
        return f.read()


def test_readme_is_a_front_door():
    text = _text()
    assert len(text.splitlines()) <= 400
    assert "make demo" in text and "make test" in text
    assert not re.search(r"\b(issue \d+|session)\b", text, re.I)


def test_readme_tables_are_those_of_the_committed_results():
    assert readme_tables.rewrite(README, readme_tables.RESULTS, check=True)
    assert "| `penumbra_casting` |" in readme_tables.tables()


def test_every_option_the_readme_shows_is_taken_by_the_parser():
    text = _text()
    section = text[text.index("## Command line"):text.index("### Passes that composite")]
    block = section.split("```")[1]                    # the synopsis
    shown = set(re.findall(r"--[a-z][a-z-]+", block))
    parser = cli.build_parser()
    taken = set()
    for action in parser._subparsers._group_actions[0].choices.values():
        for a in action._actions:
            taken.update(o for o in a.option_strings if o.startswith("--"))
    assert shown and shown <= taken, sorted(shown - taken)
