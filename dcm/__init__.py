"""dcm: a Diffusion Contact Model for learning variable impedance control."""

__version__ = "0.2.0"
