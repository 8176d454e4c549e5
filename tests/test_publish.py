"""The README's generated tables equal what their committed evidence gives
(``benchmarks/publish.py``), and the check notices a table edited by hand."""

import importlib.util
import re
from pathlib import Path

import pytest

PUBLISH = Path(__file__).resolve().parent.parent / "benchmarks" / "publish.py"


@pytest.fixture(scope="module")
def publish():
    spec = importlib.util.spec_from_file_location("publish", PUBLISH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_published_block_matches_its_evidence(publish):
    text = publish.README.read_text()
    names = {m[1] for m in publish._BLOCK.findall(text)}
    assert names == set(publish.BLOCKS), names  # every writer is published, nothing else
    assert publish.main(["--check"]) == 0


def test_check_notices_a_hand_edited_number(publish):
    text = publish.README.read_text()
    body = publish.BLOCKS["heldout-cells"]()
    rows = body.index("\n", body.index("|---"))  # the first figure below the header, changed
    at = rows + re.search(r"\d", body[rows:]).start()
    wrong = body[:at] + str((int(body[at]) + 1) % 10) + body[at + 1 :]
    edited = text.replace(body, wrong, 1)
    assert edited != text
    fixed, changed = publish.render(edited)
    assert changed == ["heldout-cells"] and fixed == text
    with pytest.raises(SystemExit, match="no writer"):
        publish.render("<!-- publish:nothing -->\nx\n<!-- /publish:nothing -->")
