"""The paper's nine models (its Table 1): tags by hyperparameters, the model its claims single
out, and its figures' groups and colours."""

from __future__ import annotations

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


def tag(k: int, memory: int) -> str | None:
    """The paper's tag of a model with these hyperparameters, or None outside its grid."""
    return LABELS.get((k, memory))
