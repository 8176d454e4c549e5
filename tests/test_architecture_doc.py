"""docs/architecture.md's "Where to change what" points where the code is: every task the
project promises extenders has its bullet, and every file, module attribute and config key a
bullet names exists (so a move or rename in the code fails here until the doc follows)."""

from __future__ import annotations

import dataclasses
import importlib
import re
from pathlib import Path

from jaxlc import config
from jaxlc.sim.state import EnvParams

ROOT = Path(__file__).resolve().parent.parent
TASKS = (
    "Change the reward",
    "Add a learner",
    "Study another grid",
    "Randomise the task",
    "Change the ego's dynamics",
)
MODULES = {p.stem: p for p in (ROOT / "jaxlc").rglob("*.py") if p.stem != "__init__"}


def _bullets() -> dict[str, str]:
    text = (ROOT / "docs" / "architecture.md").read_text()
    section = text.split("## Where to change what\n")[1].split("\n## ")[0]
    items = re.split(r"\n- \*\*", "\n" + section.strip())[1:]
    return {item.split("**")[0]: item for item in items}


def _module(dotted: str) -> object:
    """``jaxlc.X.Y`` for a dotted path under jaxlc, or the module whose file stem is ``dotted``."""
    if dotted in MODULES:
        rel = MODULES[dotted].relative_to(ROOT).with_suffix("")
        return importlib.import_module(".".join(rel.parts))
    return importlib.import_module(f"jaxlc.{dotted}")


def _resolves(token: str, names: list[object]) -> bool:
    """A path that exists, a config key, an EnvParams field, ``module.attr`` (or a method of a
    class of that module), or a bare name of a module the bullet names."""
    token = token.split(" = ")[0].split("[")[0].split("..")[0].removesuffix("-ed")
    if token.endswith(".py") or "/" in token:
        return (ROOT / "jaxlc" / token).exists() or (ROOT / token).exists()
    head, _, attr = token.rpartition(".")
    if head == "params":
        return attr in {f.name for f in dataclasses.fields(EnvParams)}
    sections = {
        f.name: type(getattr(config.Config(), f.name)) for f in dataclasses.fields(config.Config)
    }
    if head in sections and attr in {f.name for f in dataclasses.fields(sections[head])}:
        return True
    if head:
        try:
            module = _module(head)
        except ImportError:
            return False
        classes = [c for c in vars(module).values() if isinstance(c, type)]
        return hasattr(module, attr) or any(attr in vars(c) for c in classes)  # env.step
    return any(hasattr(m, token) for m in names)


def _named_modules(tokens: list[str]) -> list[object]:
    """The modules a bullet names: its ``sim/x.py``-style files and the heads of ``x.attr``."""
    out = []
    for t in tokens:
        stem = Path(t).stem if t.endswith(".py") else t.split(".")[0]
        if (t.endswith(".py") or "." in t) and stem in MODULES:
            out.append(_module(stem))
    return out


def test_every_promised_task_has_its_bullet() -> None:
    assert set(TASKS) <= set(_bullets())


def test_every_place_a_bullet_names_exists() -> None:
    for title, text in _bullets().items():
        tokens = re.findall(r"`([^`]+)`", text)
        names = _named_modules(tokens)
        for token in tokens:
            if token.startswith("[") or not re.match(r"[A-Za-z_]", token):
                continue  # a TOML table or a value
            assert _resolves(token, names), f"{title}: `{token}` is not where the doc says"
