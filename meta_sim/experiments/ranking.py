"""How E1 and E2 rank the bank: per roof kind, the bank's textures by the HSV similarity to a true
texture (``meta_sim/sim/textures/similarity.py``), and the tie-aware top-n credit of a prediction
(the paper's scoring, section 5.4). ``evaluate`` scores with it and ``breakdown`` explains its misses.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

KIND_OF = {"flat_roof": "flat", "sloped_roof": "sloped"}
OTHER_KIND = {"flat": "sloped", "sloped": "flat"}


@dataclass(frozen=True)
class Ranking:
    """The bank's textures of one kind by similarity to one true texture, nearest first."""

    ids: tuple[str, ...]
    similarity: tuple[float, ...]

    def credit(self, predicted: str, n: int) -> float:
        """1 when ``predicted`` is among the ``n`` nearest textures, else 0. Textures tied with the
        n-th nearest share the places left (a tie decided by a fair coin, in expectation): a held-out
        texture whose colours no bank texture has is equally far (similarity 0) from dozens, and
        deciding such ties by bank order would make a hit depend on where a texture is listed."""
        if predicted not in self.ids:
            return 0.0
        if n >= len(self.ids):
            return 1.0
        mine = self.similarity[self.ids.index(predicted)]
        edge = self.similarity[n - 1]
        if mine != edge:
            return float(mine > edge)
        better = sum(1 for v in self.similarity if v > edge)
        tied = sum(1 for v in self.similarity if v == edge)
        return (n - better) / tied

    def closeness(self, predicted: str) -> float:
        """``predicted``'s similarity to the truth as a share of the nearest bank texture's (1: nothing in
        the bank is nearer; 0 for a texture outside the ranking). Unlike top-n, it still means something
        for a true texture nothing in the bank resembles: there every place of the top 10 is near 0 in
        similarity, and the share says how much of the little the bank offers the choice got. When even the
        nearest texture has similarity 0, every choice is as good: 1."""
        if predicted not in self.ids:
            return 0.0
        best = self.similarity[0]
        return 1.0 if best <= 0 else float(self.similarity[self.ids.index(predicted)]) / float(best)

    def place(self, texture: str) -> int:
        """1 + the number of textures strictly nearer than ``texture`` (ties share the best place)."""
        mine = self.similarity[self.ids.index(texture)]
        return 1 + sum(1 for v in self.similarity if v > mine)


def rankings(experiment: str, bank, heldout, across: bool = False) -> dict:
    """Per roof kind: true texture id -> its ``Ranking`` of the bank's textures of that kind.

    With ``across`` the true textures are those of the *other* kind: under "flat", each sloped true
    texture ranks the bank's flat textures (how near a flat texture is to a target's sloped roof).
    """
    from ..sim.textures import SIMILARITY_FILE, SIMILARITY_TO_DEFAULT_FILE, load_similarity, rank_by_similarity

    sim = load_similarity(Path(heldout.root if experiment == "e2" else bank.root) /
                          (SIMILARITY_TO_DEFAULT_FILE if experiment == "e2" else SIMILARITY_FILE))
    truth_bank = heldout if experiment == "e2" else bank

    def ranking(truth: str, kind: str) -> Ranking:
        order = rank_by_similarity(truth, bank.ids(kind), sim)
        return Ranking(tuple(order), tuple(sim.value(truth, t) for t in order))

    return {kind: {t: ranking(t, kind) for t in truth_bank.ids(OTHER_KIND[kind] if across else kind)}
            for kind in ("flat", "sloped")}
