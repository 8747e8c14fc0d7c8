"""gprbot: ground-penetrating-radar inspection robot runtime."""

__version__ = "0.1.0"
