"""README.md is a manual: short, its API example near the top and runnable, and every link of
it, of docs/ and of the benchmarks' READMEs and reports pointing at something that exists."""

from __future__ import annotations

import contextlib
import io
import re
import shutil
from pathlib import Path

import pytest

from jaxlc.sim.reward import REASONS

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
MAX_LINES, EXAMPLE_BY = 250, 80
DOCS = [
    README,
    *sorted((ROOT / "docs").glob("*.md")),
    *sorted((ROOT / "benchmarks").rglob("*.md")),  # the evidence, which drops heavy files
]
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _example() -> tuple[int, str]:
    """The first Python block of the README: its first line's number and its code."""
    lines = README.read_text().splitlines()
    start = lines.index("```python") + 1
    end = lines.index("```", start)
    return start + 1, "\n".join(lines[start:end])


def test_the_readme_is_a_manual_with_its_example_near_the_top() -> None:
    assert len(README.read_text().splitlines()) <= MAX_LINES
    first, _ = _example()
    assert first <= EXAMPLE_BY, first


def test_the_readme_example_drives_a_trained_policy(smoke_run, tmp_path, monkeypatch) -> None:
    # smoke_run is run_sweep(configs/smoke.toml, progress=False): the command the README gives
    shutil.copytree(smoke_run[0], tmp_path / "runs" / "smoke")
    monkeypatch.chdir(tmp_path)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(_example()[1], str(README), "exec"), {})
    reason, _, steps, *_ = out.getvalue().split()
    assert reason in REASONS[1:] and int(steps) > 0, out.getvalue()


def _anchors(path: Path) -> set[str]:
    """GitHub's anchors of a Markdown file's headings."""
    heads = re.findall(r"^#+ (.+)$", path.read_text(), flags=re.M)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in heads}


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_link_resolves(doc: Path) -> None:
    broken = []
    for target in LINK.findall(doc.read_text()):
        if re.match(r"[a-z]+:", target):  # a web address
            continue
        file, _, anchor = target.partition("#")
        path = (doc.parent / file).resolve() if file else doc
        if not path.exists():
            broken.append(target)
        elif anchor and path.suffix == ".md" and anchor not in _anchors(path):
            broken.append(target)
    assert not broken, broken
