"""The paper's claims: each with the sentence it rests on and the rule it is decided by.

(a)-(c) are the paper's Fig. 3/4 comparisons, decided on learning-speed measures of the
training curves (``jaxlc.evaluation.convergence``); (d) is its 100% success, decided on the
held-out failure bound (``jaxlc.evaluation.heldout``). The README's verdict, ``report.md``,
``eval/convergence.json`` and ``eval/heldout.json`` name these and no others.
"""

from __future__ import annotations

from jaxlc.paper.grid import BEST_TAG

# (claim, the tag pairs "X better than Y" it rests on, the measures it is decided on).
COMPARISONS = (
    (
        "(c) ① and ② converge better than ③ (Fig. 3a)",
        (("①", "③"), ("②", "③")),
        ("converged", "auc"),
    ),
    (
        "(a, b) ④ converges fast and is best of ①④⑤ (Fig. 3b)",
        (("④", "①"), ("④", "⑤")),
        ("converged", "auc", "plateau"),
    ),
    ("(b) ⑦ is best of ②⑥⑦ (Fig. 3c)", (("⑦", "②"), ("⑦", "⑥")), ("auc", "plateau")),
    ("(a) ④ converges faster than ⑦ (Figs. 3d, 4a)", (("④", "⑦"),), ("converged", "steps_rise")),
)
CLAIM_D = f"(d) {BEST_TAG} succeeds in 100% of lane changes"
SOLVED = 0.99  # a success rate that counts as the paper's 100%: (d) holds when failures <= 1%
# What the paper shows for each claim, by its tag.
SHOWS = {
    "(c)": "Fig. 3a: ① and ② show a better converging trend than ③",
    "(a, b)": "Fig. 3b: among ①④⑤, ④ converges fast and has the best performance",
    "(b)": "Fig. 3c: among ②⑥⑦, ⑦ shows the best performance",
    "(a)": "Figs. 3d, 4a: ④ converges faster than ⑦; its manoeuvring steps rise earlier",
    "(d)": "Fig. 6, §IV-C: ④ completes 100% of the lane changes of 100 test cases",
}
