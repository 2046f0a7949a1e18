"""`python -m meta_sim.cli`: the same as `meta-sim`."""

from . import main

main()
