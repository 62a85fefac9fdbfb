"""Edge agent: streaming gearbox-wear monitor for robot joints (see docs/ARCHITECTURE.md)."""

__version__ = "0.1.0"
