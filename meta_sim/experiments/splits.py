"""Where a choice may be made and where a figure is reported: the validation and test splits of E1 and E2.

A setting of an experiment is a set of target seeds (each seed draws its own target designs and
cities, ``evaluate.target_jobs``) and, for E2, the held-out texture set the targets' roofs come from.

* ``validation``: anything may be chosen on it (a default, an architecture, a search setting, a
  profile) and it may be looked at as often as needed. It holds target seed 1, where every choice
  of meta-sim so far was made (``make bench-nams``'s targets before the splits), seed 7, which issue
  20 looked at, and seed 2. E2 uses the fifth held-out set, ``heldout-v5`` (made after ``heldout-v4``): the
  fourth set's 10 + 10 textures and 20 + 20 drawn by seeded code under the same conditions, against every set
  before it. The fourth set alone (``heldout-v4``, colours no set before it has) was E2's validation for a day:
  on 10 textures per kind it chose a roof match the test split did not confirm, so the split grew threefold
  before the next choice; ``VALIDATION_V4`` names the defaults chosen on it. Before that E2 validation used the
  first set, ``heldout-v1``, whose colours the bank shares, so its choices never saw a colour the bank lacks,
  the failure the test split shows; ``VALIDATION_V1`` names the defaults chosen there.
* ``test``: used only to report. Its seeds (21, 22, 23) were never used before this split was
  declared, and E2 uses the second held-out set, ``heldout-v2``, generated for it
  (``meta_sim/sim/textures/procedural.py``), whose colours neither the bank nor ``heldout-v1`` has.
  Nothing may be chosen by looking at its figures: a choice made there makes it a validation split.
* ``check``: report only, like ``test``, and not run by the benches: fresh seeds (31, 32, 33) and, for E2, the
  third held-out set, ``heldout-v3``, made after the test split's figures had suggested a change
  to the search (its numbers were chosen on validation). It confirms such a change on targets nothing ever
  looked at: `meta-sim eval e1|e2 --split check`.

Pure Python: imported by the CLI without torch.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from ..core.errors import MetaSimError

SPLIT_NAMES = ("validation", "test")  # the splits every bench measures
ALL_SPLIT_NAMES = SPLIT_NAMES + ("check",)
REPORT_ONLY = ("test", "check")
EXPERIMENTS = ("e1", "e2")
FIRST_HELDOUT = "heldout-v1"  # sim.textures.procedural.FIRST_HELDOUT: what a single seed's E2 uses
# Target cities are TARGET_CITY_SEED + 1000 * seed + group (evaluate.target_jobs): more groups than this
# per seed would reach the next seed's cities, so two seeds of one split would share cities.
GROUPS_PER_SEED = 1000


@dataclass(frozen=True)
class Split:
    """The target groups of one experiment: a name, the target seeds, and (E2) the held-out set."""

    experiment: str
    name: str
    seeds: tuple[int, ...]
    heldout: str | None = None  # E2's texture set; None for E1, whose targets use the bank

    def check(self, groups_per_seed: int) -> Split:
        """MetaSimError when ``groups_per_seed`` groups of each seed would overlap another seed's cities."""
        if len(self.seeds) > 1 and groups_per_seed > GROUPS_PER_SEED:
            raise MetaSimError(f"the {self.name} split of {self.experiment.upper()} draws from {len(self.seeds)} "
                               f"target seeds: at most {GROUPS_PER_SEED} target groups per seed, not "
                               f"{groups_per_seed}")
        return self

    @property
    def touches_test(self) -> bool:
        """Whether these targets share a seed or (E2) the texture set with the experiment's test or check
        split: figures measured on them may be reported, never used to choose anything."""
        return self.report_split is not None

    @property
    def report_split(self) -> str | None:
        """The name of the report-only split (test, check) these targets share a seed or texture set with."""
        for name in REPORT_ONLY:
            other = SPLITS[(self.experiment, name)]
            if set(self.seeds) & set(other.seeds) or (self.heldout is not None and self.heldout == other.heldout):
                return name
        return None

    def to_dict(self) -> dict:
        return {"experiment": self.experiment, "name": self.name, "seeds": list(self.seeds),
                "heldout": self.heldout}


# What E2's intervals resample (``evaluate.texture_clusters``), as a result records it; a result without it
# resampled the target groups, as E1's still do.
E2_INTERVALS = "held-out textures"

VALIDATION_SEEDS = (1, 2, 7)
TEST_SEEDS = (21, 22, 23)
CHECK_SEEDS = (31, 32, 33)
SPLITS = {
    ("e1", "validation"): Split("e1", "validation", VALIDATION_SEEDS),
    ("e1", "test"): Split("e1", "test", TEST_SEEDS),
    ("e2", "validation"): Split("e2", "validation", VALIDATION_SEEDS, "heldout-v5"),
    ("e2", "test"): Split("e2", "test", TEST_SEEDS, "heldout-v2"),
    ("e1", "check"): Split("e1", "check", CHECK_SEEDS),
    ("e2", "check"): Split("e2", "check", CHECK_SEEDS, "heldout-v3"),
}


def get_split(experiment: str, name: str) -> Split:
    """The split ``name`` of ``experiment``; MetaSimError naming the choices for anything else."""
    if experiment not in EXPERIMENTS:
        raise MetaSimError(f"unknown experiment {experiment!r}; choose one of {', '.join(EXPERIMENTS)}")
    if name not in ALL_SPLIT_NAMES:
        raise MetaSimError(f"unknown split {name!r}; choose one of {', '.join(ALL_SPLIT_NAMES)}")
    return SPLITS[(experiment, name)]


def spread(seeds: int, per_seed: int, n: int) -> list[int]:
    """Indices of ``n`` target groups (at most all of them) of a split whose groups come seed after seed,
    ``per_seed`` each, taken in turn from each seed: the first group of every seed, then the second, ..."""
    order = [s * per_seed + k for k in range(per_seed) for s in range(seeds)]
    return sorted(order[:n])


def single_seed(experiment: str, seed: int, heldout: str = FIRST_HELDOUT) -> Split:
    """The targets of one seed (`meta-sim eval --seed`), E2's from ``heldout``. Named after the split
    the seed belongs to, so that a figure measured on it says whether it may be used to choose."""
    if experiment not in EXPERIMENTS:
        raise MetaSimError(f"unknown experiment {experiment!r}; choose one of {', '.join(EXPERIMENTS)}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise MetaSimError(f"a target seed is a whole number from 0, not {seed!r}")
    split = Split(experiment, f"seed {seed}", (seed,), heldout if experiment == "e2" else None)
    validation = SPLITS[(experiment, "validation")]
    if split.touches_test:
        return replace(split, name=f"seed {seed}, of the {split.report_split} split")
    if seed in validation.seeds and split.heldout == validation.heldout:
        return replace(split, name=f"seed {seed}, of the validation split")
    return split


# The defaults meta-sim chose by measuring accuracy, each with where it is defined and what it was chosen
# on. Before the splits existed every choice on targets was made on `make bench-nams`'s and `make
# bench-tradeoff`'s targets, target seed 1 with heldout-v1: the validation split. At first E2's
# validation split used heldout-v1 (``VALIDATION_V1``), then for a day heldout-v4 (``VALIDATION_V4``); a choice
# that scored E2 there names it. Two were
# measured on renders that are no target at all. docs/design.md ("Splits") names each, and a test keeps this
# table, the code and that section in step.
VALIDATION = "validation"
VALIDATION_V1 = "validation, E2 on heldout-v1"
VALIDATION_V4 = "validation, E2 on heldout-v4"
TRAINING_RENDERS = "training renders, no target"
MEASURED_DEFAULTS = {
    "architecture additive": ("meta_sim.nams.model:DEFAULT_ARCHITECTURE", VALIDATION_V1),
    "roof-colour histograms": ("meta_sim.pipeline.workflow:ModelSettings.roof_colour", VALIDATION_V1),
    "segmenter roof finder": ("meta_sim.pipeline.workflow:ModelSettings.roof_finder", VALIDATION_V1),
    "roof-weight power 4": ("meta_sim.pipeline.workflow:ModelSettings.roof_weight_power", VALIDATION_V1),
    "score-cone roof histograms": ("meta_sim.pipeline.workflow:ModelSettings.roof_score_cone", VALIDATION_V1),
    "search colour comparison": ("meta_sim.pipeline.roofcolour:SEARCH_COLOUR", VALIDATION),
    "far-target search": ("meta_sim.pipeline.roofcolour:SEARCH_FAR", VALIDATION_V4),
    "far-target margin": ("meta_sim.pipeline.roofcolour:SEARCH_FAR_MARGIN", VALIDATION_V4),
    "far-target roof match": ("meta_sim.pipeline.roofcolour:SEARCH_MATCH", VALIDATION),
    "exhaustive search": ("meta_sim.nams.search:resolve_method", VALIDATION_V1),
    "CONTINUOUS_SEARCH": ("meta_sim.experiments.evaluate:CONTINUOUS_SEARCH", VALIDATION_V1),
    "fastest_adjoint_keeping_e1": ("meta_sim.experiments.bench:fastest_adjoint", VALIDATION),
    "training set 600 x 2": ("meta_sim.pipeline.dataset:DatasetConfig.designs", VALIDATION),
    "profiles fast, balanced and paper": ("meta_sim.pipeline.profiles:PROFILES", VALIDATION),
    "fast exposure 3.3": ("meta_sim.sim.quality:FAST_EXPOSURE", TRAINING_RENDERS),
    "colour-texture features": ("meta_sim.pipeline.features:ColourTexture", TRAINING_RENDERS),
}
