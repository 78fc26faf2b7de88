"""dcm: a Diffusion Contact Model for learning variable impedance control."""

__version__ = "0.1.0"
