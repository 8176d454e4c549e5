"""examples/walkthrough.ipynb runs top to bottom (on a one-model grid) and reports what it
should: success rates in [0, 1] over lane changes that happened, the scripted controller's
near 1, a trained run with a checkpoint, and its figure."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat", reason="optional: pip install -e '.[dev]'")
nbclient = pytest.importorskip("nbclient", reason="optional: pip install -e '.[dev]'")

NOTEBOOK = Path(__file__).resolve().parent.parent / "examples" / "walkthrough.ipynb"
# One model of 20 episodes and smaller evaluation rollouts: compiling is most of the time.
TINY = """
OVERRIDES = ["grid.k=[1]", "grid.memory=[256]", "train.episodes=20", "train.checkpoint_every=20"]
RUN_DIR = {run_dir!r}
ENVS, STEPS = 16, 800
"""
RATE = r"{who}: success rate ([0-9.]+) over (\d+) lane changes"


def _rate(text: str, who: str) -> tuple[float, int]:
    found = re.findall(RATE.format(who=who), text)
    assert len(found) == 1, (who, text)
    return float(found[0][0]), int(found[0][1])


def test_the_committed_notebook_has_no_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code)


def test_the_walkthrough_runs_and_reports(tmp_path):
    nb = nbformat.read(NOTEBOOK, as_version=4)
    (i,) = [i for i, c in enumerate(nb.cells) if "parameters" in c.metadata.get("tags", [])]
    run_dir = tmp_path / "run"
    nb.cells.insert(i + 1, nbformat.v4.new_code_cell(TINY.format(run_dir=str(run_dir))))
    client = nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()  # raises CellExecutionError, with the cell and traceback, if a cell fails
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    scripted, n_scripted = _rate(text, "scripted controller")
    learned, n_learned = _rate(text, "learned policy")
    assert n_scripted > 0 and n_learned > 0
    assert 0.9 <= scripted <= 1.0  # the reference controller completes its lane changes
    assert 0.0 <= learned <= 1.0
    summary = json.loads((run_dir / "summary.json").read_text())
    assert [m["episodes"] for m in summary["models"]] == [20]  # the overrides reached the sweep
    assert "ep00020.msgpack" in text  # the checkpoint that was loaded
    figure = run_dir / "walkthrough.png"
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert any("image/png" in o.get("data", {}) for o in outputs)  # shown in the notebook
