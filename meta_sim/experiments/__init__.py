"""The paper's experiments and our benchmarks: E1/E2 evaluation, bench-render, bench-nams,
bench-farm, bench-tradeoff and the roof-colour reference. Nothing below imports them."""
