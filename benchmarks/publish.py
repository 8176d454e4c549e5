"""Published tables written from committed evidence, never typed.

    python -m benchmarks.publish            # rewrite every block of README.md, docs/ and
                                                    # the study folders' README.md
    python -m benchmarks.publish --check    # exit 1 naming each block that differs

A block is the text of a document between ``<!-- publish:NAME -->`` and
``<!-- /publish:NAME -->``; ``BLOCKS[NAME]`` writes it from the committed folders under
``benchmarks/`` (a study's ``eval/`` files as ``python -m jaxlc.evaluate`` wrote them, a
benchmark session's CSVs). The writers live in ``tables/`` beside this file (a namespace
package), one module per subject, each naming the folders it reads at its top. Each block
appears once, in one of ``DOCS``. ``tests/test_publish.py`` runs the check, so a table that
no longer matches its evidence fails the suite.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from pathlib import Path

from benchmarks.tables import gpu, heldout, joint, learning, pairs, roads, speed, verdict

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
# The documents, and the study folders' READMEs, which hold the tables of superseded studies.
DOCS = (
    README,
    ROOT / "docs" / "results.md",
    ROOT / "docs" / "benchmarks.md",
    *sorted((ROOT / "benchmarks").glob("*/README.md")),
)
MODULES = (verdict, heldout, roads, joint, pairs, speed, gpu, learning)


def _blocks() -> dict[str, Callable[[], str]]:
    """Every module's writers by block name; a name two modules claim is an error."""
    blocks: dict[str, Callable[[], str]] = {}
    for module in MODULES:
        twice = blocks.keys() & module.BLOCKS.keys()
        if twice:
            raise SystemExit(f"block(s) {sorted(twice)} written twice ({module.__name__})")
        blocks.update(module.BLOCKS)
    return blocks


BLOCKS = _blocks()
_BLOCK = re.compile(r"(<!-- publish:([\w-]+) -->\n)(.*?)(<!-- /publish:\2 -->)", re.S)


def render(text: str) -> tuple[str, list[str]]:
    """``(new text, names of the blocks that changed)``; an unknown block name is an error."""
    changed: list[str] = []

    def fill(m: re.Match[str]) -> str:
        name = m.group(2)
        if name not in BLOCKS:
            raise SystemExit(f"block '{name}': no writer in benchmarks/tables/")
        body = BLOCKS[name]() + "\n"
        if body != m.group(3):
            changed.append(name)
        return m.group(1) + body + m.group(4)

    return _BLOCK.sub(fill, text), changed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 on a difference")
    args = ap.parse_args(argv)
    differ = []
    for doc in DOCS:
        text, changed = render(doc.read_text())
        differ += [f"{doc.relative_to(ROOT)} block '{name}'" for name in changed]
        if not args.check:
            doc.write_text(text)
    if args.check:
        for where in differ:
            print(f"{where} differs from its evidence: python -m benchmarks.publish")
        return 1 if differ else 0
    print(f"rewrote {len(differ)} block(s): {', '.join(differ) or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
