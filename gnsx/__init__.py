"""gnsx: learned particle simulation (simplified and original GNS) as an experiment platform."""

__version__ = "0.1.0"
