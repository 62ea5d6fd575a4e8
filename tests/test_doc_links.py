"""Every relative link of README.md and docs/*.md, and every Markdown file they name, is a file in the repository."""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")   # [text](target) and ![alt](target "title")
MD_NAME = re.compile(r"(?<![\w/.-])([\w./-]+\.md)\b")             # a bare or `quoted` name of a Markdown file


def links(text: str) -> list[str]:
    """Relative targets of Markdown links (URLs and pure #anchors left out, anchors and queries cut)."""
    out = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("#"):
            continue
        out.append(target.split("#")[0].split("?")[0])
    return out


def md_names(text: str) -> list[str]:
    """Names of Markdown files in the prose (URLs left out)."""
    return MD_NAME.findall(re.sub(r"[a-z][a-z0-9+.-]*://\S+", "", text, flags=re.I))


def resolves(doc: Path, target: str) -> bool:
    """Relative to the document (GitHub's rule), or, for a bare name in prose, anywhere under the repo root."""
    return (doc.parent / target).exists() or (ROOT / target).exists()


def test_the_link_finder_sees_links_and_names():
    text = ("see [the design](docs/design.md#units), ![fig](img/a.png \"A\"), [web](https://x.org/a.md), "
            "[top](#top) and DEVELOPERS.md or `results/main.md`")
    assert links(text) == ["docs/design.md", "img/a.png"]
    assert md_names(text) == ["docs/design.md", "DEVELOPERS.md", "results/main.md"]
    assert not resolves(ROOT / "README.md", "DEVELOPERS.md") and resolves(ROOT / "README.md", "docs/design.md")


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(doc):
    text = doc.read_text()
    dead = [t for t in links(text) if not resolves(doc, t)]
    named = [n for n in md_names(text) if not resolves(doc, n)]
    assert dead == [] and named == [], f"{doc.relative_to(ROOT)}: dead links {dead}, missing files named {named}"
    assert len(DOCS) >= 3  # README and at least docs/design.md, docs/notebooks.md
