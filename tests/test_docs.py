"""The README and docs/: a manual whose measured tables are the committed records' numbers.

No JAX: these read markdown and the JSON records in experiments/results/.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from experiments import docs

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = sorted((ROOT / "docs").glob("*.md"))
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def test_generated_tables_match_the_committed_records():
    """``python -m experiments.docs --check``: every generated block equals what the records in
    experiments/results/ give, so a number in the docs is a committed run's number."""
    assert docs.main(["--check"]) == 0


def test_every_generated_block_has_a_builder_and_is_used():
    used = set()
    for page in [README, *PAGES]:
        used |= set(re.findall(r"<!-- results: (\S+) -->", page.read_text()))
    assert used == set(docs.BLOCKS)


def test_a_stale_block_is_reported(tmp_path, monkeypatch):
    page = tmp_path / "page.md"
    page.write_text("intro\n<!-- results: robots -->\nan old table\n<!-- /results -->\nend\n")
    monkeypatch.setattr(docs, "PAGES", [page])
    assert docs.main(["--check"]) == 1
    assert page.read_text().count("an old table") == 1  # --check changes nothing
    assert docs.main([]) == 0
    text = page.read_text()
    assert "an old table" not in text and "41 of 41" in text and text.endswith("<!-- /results -->\nend\n")
    assert docs.main(["--check"]) == 0
    page.write_text("<!-- results: nonsense -->\n<!-- /results -->\n")
    with pytest.raises(KeyError, match="nonsense"):
        docs.main(["--check"])


def test_readme_is_a_short_manual():
    text = README.read_text()
    assert len(text.splitlines()) <= 220
    assert text.count("pip install -e '.[dev]' && python -m fastrl.train env=ant algo=ppo") == 1
    test_line = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]  # CI runs the README's line
    assert test_line.endswith("&& pytest") and text.count(f"    {test_line}\n") == 1
    assert not re.search(r"\bissue\s*#?\d+|#\d{1,3}\b", text, re.I), "the README names no issue numbers"
    assert "../shared" not in text
    for page in PAGES:
        assert f"(docs/{page.name})" in text, f"README does not link docs/{page.name}"


@pytest.mark.parametrize("page", [README, *PAGES], ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_resolve(page):
    missing = []
    for target in LINK.findall(page.read_text()):
        if "://" in target or target.startswith("mailto:"):
            continue
        if not (page.parent / target).resolve().exists():
            missing.append(target)
    assert not missing, f"{page.name}: links to missing files: {missing}"
