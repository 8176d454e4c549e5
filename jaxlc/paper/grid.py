"""The paper's nine models (its Table 1): tags by hyperparameters, the model its claims single
out, and its figures' groups and colours."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

# The paper's Table 1 numbers the models by (k, memory size).
LABELS: dict[tuple[int, int], str] = {
    (1, 2000): "①",
    (2, 2000): "②",
    (4, 2000): "③",
    (1, 4000): "④",
    (1, 8000): "⑤",
    (2, 4000): "⑥",
    (2, 8000): "⑦",
    (4, 4000): "⑧",
    (4, 8000): "⑨",
}
# The nine models' other hyperparameters (SPEC's [S] values): a model with other learning rates
# or noise is not one of the paper's, whatever its (k, memory).
HYPER = {"actor_lr": 1e-4, "critic_lr": 1e-3, "noise_sigma": 0.2}
BEST = (1, 4000)  # (k, memory) of the model the paper finds best (claims (a) and (d))
BEST_TAG = LABELS[BEST]
# Fig. 3's panels (one hyperparameter varies in each), and Figs. 3d/4's pair.
GROUPS = (
    ("(a) k = 1, 2, 4 at D = 2000", ("①", "②", "③")),
    ("(b) D = 2000, 4000, 8000 at k = 1", ("①", "④", "⑤")),
    ("(c) D = 2000, 4000, 8000 at k = 2", ("②", "⑥", "⑦")),
    ("(d) the two best", ("④", "⑦")),
)
PAIR = ("④", "⑦")
# The paper's colours where it names them (① red, ② blue, ④ dark green, ⑦ light green).
COLOURS = {
    "①": "tab:red",
    "②": "tab:blue",
    "③": "tab:orange",
    "④": "darkgreen",
    "⑤": "tab:purple",
    "⑥": "tab:brown",
    "⑦": "yellowgreen",
    "⑧": "tab:gray",
    "⑨": "tab:olive",
}


def tag(k: int | None, memory: int | None) -> str | None:
    """The paper's tag of a model with these hyperparameters, or None outside its grid."""
    return LABELS.get((k, memory))


def tag_of(model: Mapping[str, Any]) -> str | None:
    """The paper's tag of a model, cell or evaluation row (a mapping with ``k``, ``memory``
    and, where it records them, ``HYPER``'s keys), or None when it is not one of the nine: the one
    rule by which the sweep's labels, the statistics, the claims and the figures find the
    paper's models."""
    if any(model.get(name) not in (None, value) for name, value in HYPER.items()):
        return None
    return tag(model.get("k"), model.get("memory"))


def is_best(model: Mapping[str, Any]) -> bool:
    """Whether ``model`` is the one the paper finds best (``BEST``; ``tag_of``'s rule)."""
    return tag_of(model) == BEST_TAG
