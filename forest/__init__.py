"""forest: grow, render, export and look-dev very large forests."""

__version__ = "0.1.0"
