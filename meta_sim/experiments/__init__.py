"""The paper's experiments and our benchmarks: E1/E2 evaluation, bench-render, bench-nams,
bench-farm, bench-tradeoff, bench-stability and the roof-colour reference, and the validation and test
splits they are measured on (``splits``). Nothing below imports them."""
