"""meta-sim: Neural-Adjoint Meta-Simulation for synthetic overhead imagery."""

__version__ = "0.1.0"
